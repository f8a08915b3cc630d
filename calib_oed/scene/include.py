"""``include:`` in a scene file: a scene that starts from another and overrides keys.

A scene file with ``include: base.yaml`` (a path relative to the including file, or a
shipped scene name) is the included scene with the including file's keys laid over it:
mappings merge key by key, at every depth; any other value (a list, a number) replaces
the included one (a list of reflectors or obstacles is given whole). Both files state
the same ``units`` (the including file may leave them out); includes nest up to
:data:`MAX_INCLUDE_DEPTH` deep and a cycle is an error naming it.
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from calib_oed.exceptions import InputFileError, SceneError
from calib_oed.scene.yaml_file import load_yaml_file

__all__ = ["MAX_INCLUDE_DEPTH", "merge_scene_data", "resolve_includes"]

#: Deepest chain of includes.
MAX_INCLUDE_DEPTH = 8


def merge_scene_data(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``over`` laid over ``base``: mappings merged key by key, other values replaced."""
    out = dict(base)
    for key, value in over.items():
        old = base.get(key)
        out[key] = merge_scene_data(old, value) if isinstance(value, Mapping) and isinstance(old, Mapping) \
            else value
    return out


def _locate(ref: str, including: Path) -> Path:
    """A file beside the including one, else a shipped scene of that name."""
    path = including.parent / ref
    shipped = Path(str(resources.files("calib_oed.scene.shipped").joinpath(f"{ref}.yaml")))
    return shipped if not path.is_file() and "/" not in ref and shipped.is_file() else path


def resolve_includes(data: Any, path: Path, chain: tuple[Path, ...] = ()) -> Any:
    """The scene mapping of the file ``path`` (parsed as ``data``) with its includes resolved.

    Raises:
        SceneError: ``include`` not a file name, a missing or unreadable included file,
            different units, a cycle, or includes nested deeper than :data:`MAX_INCLUDE_DEPTH`.
    """
    if not isinstance(data, Mapping) or "include" not in data:
        return data
    chain = (*chain, path.resolve())
    ref = data["include"]
    if not isinstance(ref, str) or not ref.strip():
        raise SceneError(f"expected a scene file name or a shipped scene name, got {ref!r}",
                         key="include", source=str(path))
    base_path = _locate(ref.strip(), path)
    if base_path.resolve() in chain:
        names = " -> ".join(p.name for p in (*chain, base_path.resolve()))
        raise SceneError(f"include cycle {names}: a scene cannot include itself", key="include",
                         source=str(path))
    if len(chain) > MAX_INCLUDE_DEPTH:
        raise SceneError(f"includes nest deeper than {MAX_INCLUDE_DEPTH}", key="include", source=str(path))
    try:
        base = load_yaml_file(base_path, "included scene file")
    except InputFileError as exc:
        raise SceneError(f"include {ref!r}: {exc}", key="include", source=str(path)) from exc
    except yaml.YAMLError as exc:
        raise SceneError(f"include {ref!r}: YAML error in {base_path}: {getattr(exc, 'problem', exc)}",
                         key="include", source=str(path)) from exc
    if not isinstance(base, Mapping):
        raise SceneError(f"include {ref!r}: {base_path} holds no scene mapping", key="include",
                         source=str(path))
    base = resolve_includes(base, base_path, chain)
    own = {k: v for k, v in data.items() if k != "include"}
    if "units" in own and base.get("units") is not None and own["units"] != base["units"]:
        raise SceneError(f"units {own['units']} differ from those of the included {ref!r} "
                         f"({base['units']}): the overrides must be in the included scene's units",
                         key="units", source=str(path))
    return merge_scene_data(base, own)
