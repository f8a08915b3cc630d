"""Reading the text and YAML files calib_oed takes, within bounds.

Every YAML file calib_oed reads (scenes, designs, truths, sensor files, study
configurations) goes through :func:`load_yaml_file`: a :class:`yaml.SafeLoader`
subclass that refuses a key given twice in one mapping (YAML itself would keep the
last silently) and a document whose aliases expand to more than
:data:`MAX_YAML_NODES` nodes (an "alias bomb": a few lines that grow to billions of
values once a reader walks them) or that refer to themselves. Every file is
read by :func:`read_text_file`, which refuses what is not a regular file (a
device such as ``/dev/zero`` never ends) and files over a size bound.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from calib_oed.exceptions import InputFileError

__all__ = ["MAX_SMALL_YAML_BYTES", "MAX_TEXT_BYTES", "MAX_YAML_BYTES", "MAX_YAML_NODES", "load_yaml", "load_yaml_file",
           "read_text_file", "shipped_file", "shipped_names"]

#: Largest YAML file read [bytes]: a 10000-pose design.yaml has about 3 MiB.
MAX_YAML_BYTES = 8 * 2**20
#: Largest scene, truth, sensor or study file [bytes]: a scene is a few kB.
MAX_SMALL_YAML_BYTES = 2**20
#: Largest data file (measurement or design CSV) read [bytes]: about a million rows.
MAX_TEXT_BYTES = 128 * 2**20
#: Most YAML nodes a document may hold, counted before parsing (its lines and commas) and
#: once its aliases are expanded (a 10000-pose design has about 140 000); parsing costs
#: about 0.5 kB of memory and 20 us per node.
MAX_YAML_NODES = 500_000

_Base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
_MERGE = "tag:yaml.org,2002:merge"


def read_text_file(path: str | os.PathLike, what: str = "file",
                   max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of the regular file ``path`` (a leading byte-order mark dropped).

    Raises:
        InputFileError: missing, not a regular file (a folder, a device, a pipe),
            larger than ``max_bytes``, unreadable, or not UTF-8.
    """
    p = Path(path)
    try:
        if not p.exists():
            raise InputFileError(p, f"cannot read the {what}: not found")
        if p.is_dir():
            raise InputFileError(p, f"is a folder; give the {what}")
        if not p.is_file():
            raise InputFileError(p, f"is not a regular file (a device or a pipe); give the {what}")
        size = p.stat().st_size
        if size > max_bytes:
            raise InputFileError(p, f"the {what} has {size / 2**20:.1f} MiB, more than the "
                                 f"{max_bytes / 2**20:.0f} MiB calib_oed reads")
        with open(p, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputFileError(p, f"cannot read the {what}: {exc.strerror or exc}") from exc
    if len(data) > max_bytes:  # grew while read
        raise InputFileError(p, f"the {what} is larger than the {max_bytes / 2**20:.0f} MiB "
                             "calib_oed reads")
    try:
        return data.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        raise InputFileError(p, f"the {what} is not UTF-8 text ({exc.reason} at byte {exc.start})") from exc


class _StrictLoader(_Base):
    """A safe loader that refuses a key given twice in one mapping."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            first: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if key_node.tag == _MERGE:
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    earlier = first.setdefault(key, key_node)
                except TypeError:  # an unhashable key: the base class names it
                    continue
                if earlier is not key_node:
                    raise InputFileError(self.where, f"line {key_node.start_mark.line + 1}: duplicate "
                                         f"key {key!r} (first given at line {earlier.start_mark.line + 1}); "
                                         "give each key once")
        return super().construct_mapping(node, deep=deep)


def _children(node) -> list:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _check_expansion(root, where: str, limit: int) -> None:
    """Raise unless the node graph ``root`` (aliases shared) expands to <= ``limit`` nodes
    and has no cycle. Counted bottom-up, each distinct node once: linear in the file."""
    size: dict[int, int] = {}
    entered: set[int] = set()
    stack = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            entered.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in _children(node))
            if size[key] > limit:
                raise InputFileError(where, f"YAML aliases (*name) at line {node.start_mark.line + 1} "
                                     f"expand to more than {limit} values; write the data out "
                                     "or use fewer aliases")
            continue
        if key in size:
            continue
        if key in entered:
            raise InputFileError(where, f"a YAML alias at line {node.start_mark.line + 1} refers "
                                 "to a node that contains it (a recursive alias)")
        entered.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in size)


def load_yaml(text: str, where: str = "<string>", max_nodes: int = MAX_YAML_NODES) -> Any:
    """Parse one YAML document with :class:`_StrictLoader` and the alias bound.

    Raises:
        yaml.YAMLError: a syntax error.
        InputFileError: a key given twice in one mapping (with its lines), aliases that expand beyond ``max_nodes`` nodes or refer to themselves,
            or nesting deeper than Python's recursion allows.
    """
    estimate = text.count("\n") + text.count(",")  # no more nodes than these without aliases
    if estimate > max_nodes:
        raise InputFileError(where, f"the YAML holds about {estimate} values, more than the {max_nodes} "
                             "calib_oed reads from one file")
    loader = _StrictLoader(text)
    loader.where = where
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _check_expansion(node, where, max_nodes)
        return loader.construct_document(node)
    except RecursionError:
        raise InputFileError(where, "the YAML is nested too deeply") from None
    finally:
        loader.dispose()


def load_yaml_file(path: str | os.PathLike, what: str = "YAML file",
                   max_bytes: int = MAX_SMALL_YAML_BYTES) -> Any:
    """:func:`read_text_file` then :func:`load_yaml`; syntax errors as :class:`yaml.YAMLError`."""
    return load_yaml(read_text_file(path, what, max_bytes), os.fspath(path))


def shipped_names(package: str) -> list[str]:
    """Names of the ``<name>.yaml`` files shipped in ``package`` (``"calib_oed.scene.shipped"``)."""
    return sorted(p.name[:-5] for p in resources.files(package).iterdir() if p.name.endswith(".yaml"))


def shipped_file(package: str, name: str) -> Path | None:
    """The file ``<name>.yaml`` shipped in ``package``, or ``None`` if none has that name."""
    if name not in shipped_names(package):
        return None
    return Path(str(resources.files(package).joinpath(f"{name}.yaml")))
