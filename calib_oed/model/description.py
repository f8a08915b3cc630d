"""Robot descriptions: xacro files with arguments, and ``package://`` paths.

ROS robot support packages (ROS-Industrial's FANUC, ABB, KUKA, ...) ship their
robots as xacro macros that include other xacro files by ``$(find pkg)`` and
name their meshes ``package://pkg/meshes/...``. This module turns such a
description into plain URDF text and finds the package folders:

- :func:`expand_xacro` runs the ``xacro`` package (the same processor ROS
  uses) with the given arguments; ``$(find pkg)`` is resolved by
  :func:`find_package` instead of ROS's package index.
- :func:`find_package` looks for package ``pkg`` in the given folders, then
  in the folders of the ``ROS_PACKAGE_PATH`` environment variable: a folder
  ``<root>/pkg``, a root that is itself the package, or a folder below a root
  (up to :data:`SEARCH_DEPTH` levels and :data:`SEARCH_FOLDERS` folders) whose
  ``package.xml`` says ``<name>pkg</name>``.
- :func:`resolve_package_paths` finds every ``package://`` package a URDF
  uses and returns the folders Pinocchio's ``package_dirs`` needs (the parent
  of each package folder), so meshes load wherever the URDF goes
  (collision fit, mesh check, viewer). A package that cannot be found is an
  error naming the mesh and the folders searched.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

from calib_oed.exceptions import RobotLoadError

#: How deep below a search root a ``package.xml`` is looked for.
SEARCH_DEPTH = 3
#: At most this many folders are opened per search root (a root may be a home folder).
SEARCH_FOLDERS = 2000
#: File names that are xacro files.
XACRO_SUFFIXES = (".xacro",)

_PACKAGE_URI = re.compile(r"package://([^/\s\"']+)/([^\s\"']*)")


def is_xacro(path: str | os.PathLike) -> bool:
    """True for ``*.xacro`` files (``robot.urdf.xacro`` included)."""
    return str(path).endswith(XACRO_SUFFIXES)


def default_package_dirs(path: str | os.PathLike) -> tuple[str, ...]:
    """Where a description file's packages are looked for by default.

    The file's folder and, if the file sits inside a package (a folder above
    it holds ``package.xml``), the folder holding that package, so that
    ``$(find pkg)`` and ``package://pkg`` find the package itself and its
    siblings in the same workspace.
    """
    folder = Path(path).resolve().parent
    dirs = [str(folder)]
    for parent in (folder, *folder.parents):
        if (parent / "package.xml").is_file():
            dirs.append(str(parent.parent))
            break
    return tuple(dict.fromkeys(dirs))


def search_roots(package_dirs: Sequence[str | os.PathLike] = ()) -> list[Path]:
    """The folders searched for packages: ``package_dirs``, then ``ROS_PACKAGE_PATH``."""
    roots = [Path(d) for d in package_dirs]
    roots += [Path(p) for p in os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep) if p]
    return list(dict.fromkeys(r.expanduser().resolve() for r in roots))


def _package_name(folder: Path) -> str | None:
    manifest = folder / "package.xml"
    if not manifest.is_file():
        return None
    try:
        name = ET.parse(manifest).getroot().findtext("name")
    except ET.ParseError:
        return None
    return name.strip() if name else None


def find_package(name: str, package_dirs: Sequence[str | os.PathLike] = ()) -> Path | None:
    """The folder of ROS package ``name``, or None (search order in the module docstring)."""
    roots = search_roots(package_dirs)
    for root in roots:
        if (root / name).is_dir():
            return root / name
        if root.is_dir() and (root.name == name or _package_name(root) == name):
            return root
    for root in roots:
        level, opened = ([root] if root.is_dir() else []), 0
        for _ in range(SEARCH_DEPTH):
            below = []
            for f in level[: max(0, SEARCH_FOLDERS - opened)]:
                opened += 1
                try:
                    below += [c for c in sorted(f.iterdir()) if c.is_dir() and not c.name.startswith(".")]
                except OSError:
                    continue
            for folder in below:
                if _package_name(folder) == name:
                    return folder
            level = below
    return None


def _not_found(name: str, package_dirs: Sequence[str | os.PathLike], what: str) -> RobotLoadError:
    roots = [str(r) for r in search_roots(package_dirs)] or ["(none)"]
    return RobotLoadError(
        f"{what}: ROS package {name!r} not found; searched {', '.join(roots)} (robot.package_dirs, "
        "then ROS_PACKAGE_PATH); give the folder that holds the package (or the package "
        "folder itself) as robot.package_dirs in the scene file, or "
        "load_robot(..., package_dirs=[...]) in Python"
    )


def resolve_package_paths(urdf_text: str, package_dirs: Sequence[str | os.PathLike] = (),
                          where: str = "URDF", strict: bool = True) -> tuple[str, tuple[str, ...]]:
    """URDF text whose ``package://`` paths load, and the folders Pinocchio needs.

    Returns:
        The text, unchanged unless a package folder is not named like its
        package (then its ``package://pkg/`` prefix is replaced by the folder's
        absolute path), and ``package_dirs`` followed by the parent folder of
        every package found.

    Raises:
        RobotLoadError: with ``strict``, a package cannot be found or a mesh file
            is missing in it (without, such paths are left as they are: the
            collision fit names them when it needs them).
    """
    dirs = [str(Path(d)) for d in package_dirs]
    folders: dict[str, Path | None] = {}
    for pkg, rest in _PACKAGE_URI.findall(urdf_text):
        if pkg not in folders:
            folders[pkg] = find_package(pkg, package_dirs)
        folder = folders[pkg]
        if not strict:
            continue
        if folder is None:
            raise _not_found(pkg, package_dirs, f"{where}: package://{pkg}/{rest}")
        if rest and not (folder / rest).is_file():
            raise RobotLoadError(f"{where}: package://{pkg}/{rest}: no such file in the package "
                                 f"folder {folder}")
    for pkg, folder in folders.items():
        if folder is None:
            continue
        if folder.name == pkg:
            dirs.append(str(folder.parent))
        else:
            urdf_text = urdf_text.replace(f"package://{pkg}/", f"{folder}/")
    return urdf_text, tuple(dict.fromkeys(dirs))


def expand_xacro(path: str | os.PathLike, args: Mapping[str, object] | None = None,
                 package_dirs: Sequence[str | os.PathLike] = ()) -> str:
    """The URDF text of xacro file ``path`` with arguments ``args`` (``xacro path name:=value``).

    ``$(find pkg)`` resolves through :func:`find_package` (``package_dirs``,
    then ``ROS_PACKAGE_PATH``).

    Raises:
        RobotLoadError: the file is missing, the xacro is invalid, an argument
            is missing, or a package cannot be found.
    """
    import xacro
    import xacro.substitution_args as substitution

    path = Path(path)
    if not path.is_file():
        raise RobotLoadError(f"xacro file not found: {path}")
    mappings = {str(k): _arg_text(v) for k, v in (args or {}).items()}

    def find(pkg: str) -> str:
        folder = find_package(pkg, package_dirs)
        if folder is None:
            raise _not_found(pkg, package_dirs, f"{path}: $(find {pkg})")
        return str(folder)

    # xacro resolves $(find) through ROS's package index (ament_index_python);
    # swap in our search for the duration of this call only.
    original = substitution._eval_find
    substitution._eval_find = find
    try:
        doc = xacro.process_file(str(path), mappings=mappings)
        return doc.toxml()
    except RobotLoadError:
        raise
    except Exception as exc:  # xacro raises XacroException, NameError, ExpatError, ...
        inner = getattr(exc, "exc", None)
        if isinstance(inner, RobotLoadError):  # our $(find) failure, wrapped by xacro
            raise inner from None
        raise RobotLoadError(f"{path}: xacro failed: {exc}; arguments given: "
                             f"{mappings or 'none'}") from exc
    finally:
        substitution._eval_find = original


def _arg_text(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)
