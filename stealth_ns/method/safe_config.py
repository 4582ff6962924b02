"""Load a run's ``config.yml`` without executing anything it says.

nerfstudio dumps its ``TrainerConfig`` with PyYAML's python tags and reads it back with
``yaml.Loader``, which runs whatever a tag names: ``!!python/object/apply:os.system ["..."]``
in a downloaded run folder executes at load time (``ns-eval``, ``ns-viewer``, ``ns-render``).
:class:`SafeConfigLoader` is a ``yaml.SafeLoader`` that constructs only what a nerfstudio
config holds and refuses every other python tag before importing or calling anything:

* ``!!python/object:M.C``: a dataclass from an allowed module (``__new__`` plus its fields; no
  constructor, no ``__setstate__``);
* ``!!python/object/apply:M.C [args]``: only an ``Enum`` member by value from an allowed module, a
  ``pathlib`` path from strings, or ``_operator.getitem`` of two allowed classes (a generic alias
  such as ``VanillaDataManager[DepthDataset]``);
* ``!!python/name:M.X``: a class from an allowed module, or a function from ``nerfstudio.data``
  (collate functions); modules are imported only once their name is allowed;
* ``!!python/tuple`` and the plain-data tags (``python/none``, ``python/bool``, ...).

Allowed modules: ``nerfstudio.*`` except its scripts (``nerfstudio.scripts``,
``nerfstudio.process_data``, ``nerfstudio.utils.scripts``), the ``stealth_ns`` modules a config
names (attack, raster and the method's datamanager, model, pipeline, schedulers, optimizers, trainer)
and ``torch.optim``.
``safe_eval_setup`` is nerfstudio's ``eval_setup`` with this loader. docs/design/security.md.
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import inspect
import operator
import pathlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from stealth_ns.foundation.errors import StealthNSError
from stealth_ns.foundation.moved_modules import current_name

_PY = "tag:yaml.org,2002:python/"

#: Module prefixes whose classes a config may name.
ALLOWED_MODULES: tuple[str, ...] = (
    "nerfstudio",
    "stealth_ns.attack",
    "stealth_ns.method.datamanager",
    "stealth_ns.method.model",
    "stealth_ns.method.pipeline",
    "stealth_ns.method.schedulers",
    "stealth_ns.method.optimizers",
    "stealth_ns.raster",
    "stealth_ns.method.trainer",
    "torch.optim",
)
#: Never, even though under an allowed prefix: they run commands.
DENIED_MODULES: tuple[str, ...] = (
    "nerfstudio.scripts",
    "nerfstudio.process_data",
    "nerfstudio.utils.scripts",
)
#: Modules whose plain functions a config may name (``collate_fn``).
FUNCTION_MODULES: tuple[str, ...] = ("nerfstudio.data",)
_PATHS = {
    "pathlib.Path",
    "pathlib.PosixPath",
    "pathlib.WindowsPath",
    "pathlib.PurePosixPath",
    "pathlib.PureWindowsPath",
}


class UnsafeConfigError(yaml.YAMLError):
    """A tag the safe loader refuses (carries the tag for the one-line message)."""

    def __init__(self, tag: str, why: str, mark: Any = None) -> None:
        super().__init__(f"{tag}: {why}")
        self.tag, self.why, self.mark = tag, why, mark


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def module_allowed(module: str) -> bool:
    return _under(module, ALLOWED_MODULES) and not _under(module, DENIED_MODULES)


def _short(tag: str) -> str:
    return "!!" + tag[len("tag:yaml.org,2002:") :] if tag.startswith("tag:yaml.org,2002:") else tag


class SafeConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` + the python tags of a nerfstudio config (see the module docstring)."""

    def _refuse(self, node: yaml.Node, why: str) -> None:
        raise UnsafeConfigError(_short(node.tag), why, node.start_mark)

    def _resolve(self, node: yaml.Node, dotted: str) -> Any:
        """``module.attr`` -> the object, importing ``module`` only when it is allowed (a module path
        from before today's packages is read as today's: :mod:`stealth_ns.foundation.moved_modules`)."""
        module, _, attr = current_name(dotted).rpartition(".")
        if not module or not attr:
            self._refuse(node, "not a module.name")
        if not module_allowed(module):
            self._refuse(node, f"module {module} is not one a nerfstudio config uses")
        try:
            obj = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as err:
            self._refuse(node, f"cannot find it ({err})")
        defined_in = getattr(obj, "__module__", None) or ""
        if not module_allowed(defined_in):  # a re-export such as ``nerfstudio.x.os``
            self._refuse(node, f"it is defined in {defined_in or 'no module'}, not an allowed module")
        return obj

    def construct_python_name(self, suffix: str, node: yaml.Node) -> Any:
        obj = self._resolve(node, suffix)
        if inspect.isclass(obj):
            return obj
        if inspect.isfunction(obj) and _under(obj.__module__, FUNCTION_MODULES):
            return obj
        self._refuse(node, "only classes (and nerfstudio.data functions) may be named")

    def construct_python_object(self, suffix: str, node: yaml.Node) -> Any:
        cls = self._resolve(node, suffix)
        if not (inspect.isclass(cls) and dataclasses.is_dataclass(cls)):
            self._refuse(node, "only dataclasses (config objects) may be constructed")
        if not isinstance(node, yaml.MappingNode):
            self._refuse(node, "expected the object's fields as a mapping")
        instance = cls.__new__(cls)
        yield instance
        state = self.construct_mapping(node, deep=True)
        instance.__dict__.update(state)

    def construct_python_apply(self, suffix: str, node: yaml.Node) -> Any:
        if isinstance(node, yaml.SequenceNode):
            args = self.construct_sequence(node, deep=True)
        elif isinstance(node, yaml.MappingNode):
            value = self.construct_mapping(node, deep=True)
            if set(value) - {"args"}:
                self._refuse(node, "only positional arguments are accepted")
            args = list(value.get("args", []))
        else:
            self._refuse(node, "expected a list of arguments")
        if suffix in _PATHS:
            if not all(isinstance(a, str) for a in args):
                self._refuse(node, "a path takes strings")
            return getattr(pathlib, suffix.rpartition(".")[2])(*args)
        if suffix == "_operator.getitem":
            if len(args) != 2 or not all(inspect.isclass(a) for a in args):
                self._refuse(node, "only a generic alias of two allowed classes is accepted")
            return operator.getitem(*args)
        cls = self._resolve(node, suffix)
        if inspect.isclass(cls) and issubclass(cls, enum.Enum) and len(args) == 1:
            try:
                return cls(args[0])
            except ValueError as err:
                self._refuse(node, str(err))
        self._refuse(node, "calling it is not allowed (only enum values, paths and generic aliases)")

    def construct_python_refused(self, suffix: str, node: yaml.Node) -> Any:
        self._refuse(node, "not a tag a nerfstudio config uses")


def _python_dispatch(loader: SafeConfigLoader, suffix: str, node: yaml.Node) -> Any:
    kind, _, name = suffix.partition(":")
    if kind == "object":
        return loader.construct_python_object(name, node)
    if kind == "object/apply":
        return loader.construct_python_apply(name, node)
    if kind == "name":
        return loader.construct_python_name(name, node)
    return loader.construct_python_refused(suffix, node)


for _tag, _method in (
    ("none", yaml.FullLoader.construct_yaml_null),
    ("bool", yaml.FullLoader.construct_yaml_bool),
    ("str", yaml.FullLoader.construct_python_str),
    ("unicode", yaml.FullLoader.construct_python_unicode),
    ("int", yaml.FullLoader.construct_yaml_int),
    ("float", yaml.FullLoader.construct_yaml_float),
    ("list", yaml.FullLoader.construct_yaml_seq),
    ("dict", yaml.FullLoader.construct_yaml_map),
    ("tuple", yaml.FullLoader.construct_python_tuple),
):
    SafeConfigLoader.add_constructor(_PY + _tag, _method)
SafeConfigLoader.add_multi_constructor(_PY, _python_dispatch)


def load_config(config_path: Path) -> Any:
    """The ``TrainerConfig`` of a run's ``config.yml``, loaded safely; StealthNSError (one line,
    naming the file and the tag) for anything the safe loader refuses or a file that is no config."""
    from nerfstudio.engine.trainer import TrainerConfig

    config_path = Path(config_path)
    try:
        text = config_path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise StealthNSError(f"cannot read {config_path}: {err}") from None
    try:
        config = yaml.load(text, Loader=SafeConfigLoader)
    except UnsafeConfigError as err:
        line = f" (line {err.mark.line + 1})" if err.mark is not None else ""
        raise StealthNSError(
            f"refusing to load {config_path}: tag {err.tag}{line} is not allowed in a run config "
            f"({err.why}); nothing was executed (docs/design/security.md)"
        ) from None
    except yaml.constructor.ConstructorError as err:
        mark = err.problem_mark
        line = f" (line {mark.line + 1})" if mark is not None else ""
        raise StealthNSError(
            f"refusing to load {config_path}: {err.problem}{line}; nothing was executed "
            "(docs/design/security.md)"
        ) from None
    except yaml.YAMLError as err:
        raise StealthNSError(f"{config_path} is not valid YAML: {str(err).splitlines()[0]}") from None
    if not isinstance(config, TrainerConfig):
        raise StealthNSError(f"{config_path} is not a nerfstudio run config (no TrainerConfig in it)")
    return config


def safe_eval_setup(
    config_path: Path,
    test_mode: str = "test",
    update_config_callback: Callable[[Any], Any] | None = None,
) -> tuple[Any, Any, Path, int]:
    """nerfstudio's ``eval_setup`` with :func:`load_config` in place of ``yaml.Loader``.

    Returns ``(config, pipeline, checkpoint_path, step)``. The checkpoint (the latest, or
    ``load_step``'s) is found and read before the pipeline is set up (:mod:`stealth_ns.method.checkpoints`:
    ``torch.load`` with ``weights_only=True``, tensors, no code; one-line errors).
    """
    import torch
    from nerfstudio.configs.method_configs import all_methods

    from stealth_ns.method.checkpoints import find_checkpoint, read_checkpoint

    config = load_config(config_path)
    if config.method_name not in all_methods:
        raise StealthNSError(
            f"{config_path} was trained with method {config.method_name!r}, which is not installed here"
        )
    config.pipeline.datamanager._target = all_methods[config.method_name].pipeline.datamanager._target
    if update_config_callback is not None:
        config = update_config_callback(config)
    config.load_dir = config.get_checkpoint_dir()
    checkpoint_path = find_checkpoint(config.load_dir, config.load_step, flag="checkpoint folder")
    state = read_checkpoint(checkpoint_path)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    pipeline = config.pipeline.setup(device=device, test_mode=test_mode)
    pipeline.eval()
    try:
        pipeline.load_pipeline(state["pipeline"], state["step"])
    except (RuntimeError, KeyError) as err:  # another model's parameters
        reason = str(err).splitlines()[0]
        raise StealthNSError(
            f"checkpoint {checkpoint_path} does not fit the model of {config_path} ({reason})"
        ) from None
    return config, pipeline, checkpoint_path, int(state["step"])
