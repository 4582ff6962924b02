"""stealth-ns: StealthAttack (density-guided 3DGS poisoning) as a nerfstudio method plugin."""

from stealth_ns.foundation import moved_modules

__version__ = "0.1.0"

moved_modules.install()
