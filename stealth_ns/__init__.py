"""stealth-ns: StealthAttack (density-guided 3DGS poisoning) as a nerfstudio method plugin."""

__version__ = "0.1.0"
