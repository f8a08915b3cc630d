"""The bounded YAML and text reader (issue 34): duplicate keys, alias bombs, recursion, size,
files that are not regular files."""

from __future__ import annotations

import os

import pytest

from calib_oed.exceptions import ExportError, InputFileError
from calib_oed.io.atomic import atomic_write_text
from calib_oed.scene import yaml_file
from calib_oed.scene.yaml_file import load_yaml, load_yaml_file, read_text_file


def test_a_plain_document_with_a_merge_key_loads():
    data = load_yaml("a: 1\nb: &x {c: 1}\nd: {<<: *x, e: 2}\n")
    assert data == {"a": 1, "b": {"c": 1}, "d": {"c": 1, "e": 2}}


def test_a_duplicate_key_names_both_lines():
    with pytest.raises(InputFileError, match=r"line 3: duplicate key 'a' \(first given at line 1\)"):
        load_yaml("a: 1\nb: {c: 1}\na: 2\n")
    with pytest.raises(InputFileError, match="duplicate key 'c'"):
        load_yaml("b: {c: 1, c: 2}\n")


@pytest.fixture
def work(monkeypatch):
    """Counts of the reader's work: nodes visited by the alias check, values constructed,
    documents parsed (a bound on work, not on time: it holds under any load)."""
    counts = {"visited": 0, "constructed": 0, "parsed": 0}
    children, construct, parse = yaml_file._children, yaml_file._StrictLoader.construct_object, \
        yaml_file._StrictLoader.get_single_node

    def counted_children(node):
        counts["visited"] += 1
        return children(node)

    def counted_construct(self, node, deep=False):
        counts["constructed"] += 1
        return construct(self, node, deep=deep)

    def counted_parse(self):
        counts["parsed"] += 1
        return parse(self)

    monkeypatch.setattr(yaml_file, "_children", counted_children)
    monkeypatch.setattr(yaml_file._StrictLoader, "construct_object", counted_construct)
    monkeypatch.setattr(yaml_file._StrictLoader, "get_single_node", counted_parse)
    return counts


def test_an_alias_bomb_is_refused_at_once(work):
    lines = ["x0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"x{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 10)]  # 1e10 values
    with pytest.raises(InputFileError, match="expand to more than"):
        load_yaml("\n".join(lines), max_nodes=10_000)
    # each of the file's ~130 distinct nodes is visited once (not the 1e10 of the expansion),
    # and no value is built
    assert work["visited"] <= 2 * (len(lines) * 12 + 1) and work["constructed"] == 0, work
    assert len(load_yaml("\n".join(lines[:3]), max_nodes=10_000)["x2"]) == 10  # 1000 values: fine


def test_a_huge_list_is_refused_before_parsing(work):
    """An 8 MB list of numbers took 2 minutes and 0.85 GB to parse: refused before parsing."""
    text = "x: [" + ", ".join(["1.5"] * 1_600_000) + "]\n"
    with pytest.raises(InputFileError, match="more than the 500000"):
        load_yaml(text)
    assert work == {"visited": 0, "constructed": 0, "parsed": 0}


def test_a_recursive_alias_is_refused():
    with pytest.raises(InputFileError, match="recursive alias"):
        load_yaml("a: &r [1, *r]\n")


def test_size_and_kind_of_file(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("a: " + "1" * 2000 + "\n")
    with pytest.raises(InputFileError, match="more than the 0 MiB"):
        load_yaml_file(big, max_bytes=1000)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputFileError, match="not a regular file"):
        read_text_file(fifo)
    with pytest.raises(InputFileError, match="is a folder"):
        read_text_file(tmp_path)
    with pytest.raises(InputFileError, match="not found"):
        read_text_file(tmp_path / "missing")
    (tmp_path / "latin.txt").write_bytes("\u00e8".encode("latin-1"))
    with pytest.raises(InputFileError, match="not UTF-8"):
        read_text_file(tmp_path / "latin.txt")


def test_atomic_write_never_replaces_a_device_or_pipe(tmp_path):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(ExportError, match="not a regular file"):
        atomic_write_text(fifo, "x")
    assert fifo.is_fifo()
