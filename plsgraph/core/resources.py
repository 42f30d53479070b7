"""Files that ship inside the package (board definitions, camera presets) and the one YAML loader every
user-supplied settings file goes through."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

from ..errors import InputError

KINDS = ("boards", "cameras")


def bundled_dir(kind: str) -> Path:
    """The package-data folder of one kind (``boards`` or ``cameras``), wherever the package is installed."""
    if kind not in KINDS:
        raise ValueError(f"unknown bundled kind {kind!r}")
    return Path(str(resources.files("plsgraph") / "data" / kind))


def bundled_names(kind: str) -> list[str]:
    """Names (file stems) of the bundled files of one kind, sorted."""
    return sorted(p.stem for p in bundled_dir(kind).glob("*.yaml"))


def bundled_file(kind: str, name: str) -> Path | None:
    """The bundled YAML of that name, or None."""
    p = bundled_dir(kind) / f"{Path(name).stem}.yaml"
    return p if p.is_file() else None


def read_yaml_mapping(path: str | Path, what: str) -> dict[str, Any]:
    """Load a YAML file that must hold a mapping; every failure is an :class:`InputError` naming ``what``
    (e.g. "board file") and the path."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} {path} does not exist")
    try:
        with open(path) as f:
            d = yaml.safe_load(f)
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"{what} {path} is not valid YAML: {exc}") from exc
    if not isinstance(d, dict):
        raise InputError(f"{what} {path} is not a YAML mapping")
    return d
