"""The one YAML reader of angiohull: safe, and strict about what a hand-written file may hold.

Every YAML file the package reads (``study.yaml``, experiment configurations, a run's
``config.yaml``) goes through :func:`load_yaml`, which on top of PyYAML's safe loader refuses

* text that is not UTF-8 (the message gives the line and column of the first bad byte);
* files larger than :data:`MAX_YAML_BYTES`;
* a document that aliases (``*name``) expand to more than :data:`MAX_YAML_NODES` values, or to a
  structure that contains itself: a few lines of aliases can stand for billions of values
  ("billion laughs"), which every later check would walk through;
* nesting deeper than :data:`MAX_YAML_DEPTH` levels, aliases expanded (the composer recurses per
  level);
* a key given twice in one mapping (PyYAML silently keeps the last one); the message names the key
  and both lines.

Errors are raised as the caller's :class:`~angiohull.errors.AngiohullError` subclass, each one
line starting with ``where`` (usually the file's path). Imports nothing from angiohull but errors.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Union

import yaml

from .errors import AngiohullError

__all__ = ["load_yaml", "read_yaml_file", "MAX_YAML_BYTES", "MAX_YAML_DEPTH", "MAX_YAML_NODES"]

MAX_YAML_BYTES = 8 * 1024 * 1024
"""Largest YAML file read (8 MiB): a study of a hundred views takes a few kilobytes."""

MAX_YAML_DEPTH = 64
"""Deepest nesting of mappings and lists accepted; angiohull's formats use fewer than ten levels."""

MAX_YAML_NODES = 1_000_000
"""Most values (scalars, lists, mappings, keys included) a document may hold with its aliases
expanded; a study of a thousand views holds a few tens of thousands."""


class _Refused(Exception):
    """A document angiohull does not read (raised inside the loader, turned into the caller's error)."""

    def __init__(self, message: str):
        super().__init__(message)
        self.message = message


def _line(mark: Any) -> str:
    return f"line {mark.line + 1}, column {mark.column + 1}" if mark is not None else "an unknown line"


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader with depth, alias and duplicate-key checks."""

    def __init__(self, stream: str):
        super().__init__(stream)
        self._depth = 0

    def compose_document(self) -> Any:
        node = super().compose_document()
        _check_expanded(node)
        return node

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            return super().compose_node(parent, index)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                mark = self.peek_event().start_mark
                raise _Refused(f"nested more than {MAX_YAML_DEPTH} levels deep (at {_line(mark)}); angiohull's "
                               f"files need fewer than ten")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node: Any, deep: bool = False) -> Any:
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # a collection as key: PyYAML reports it as unhashable; '<<' merges (explicit keys win)
                key = self.construct_object(key_node, deep=deep)
                try:
                    first = seen.get(key)
                except TypeError:
                    continue
                if first is not None:
                    raise _Refused(f"duplicate key {key!r} at {_line(key_node.start_mark)} (first given at "
                                   f"{_line(first)}); each key may appear once in a mapping")
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


def _children(node: Any) -> list[Any]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [item for pair in node.value for item in pair]
    return []


def _check_expanded(root: Any) -> None:
    """Refuse a node graph that, aliases expanded, is cyclic, holds more than MAX_YAML_NODES values
    or is nested deeper than MAX_YAML_DEPTH (iterative: the graph may be deep)."""
    if root is None:
        return
    size: dict[int, tuple[int, int]] = {}  # id(node) -> (values, depth), once expanded
    visiting: set[int] = set()
    stack: list[tuple[Any, bool]] = [(root, False)]
    while stack:
        node, finished = stack.pop()
        key = id(node)
        if finished:
            count, depth = 1, 1
            for child in _children(node):
                child_count, child_depth = size[id(child)]
                count, depth = min(count + child_count, MAX_YAML_NODES + 1), max(depth, child_depth + 1)
            visiting.discard(key)
            size[key] = (count, depth)
            if count > MAX_YAML_NODES:
                raise _Refused(f"the document, its aliases (*name) expanded, holds more than {MAX_YAML_NODES:,} values "
                               f"(the mapping or list at {_line(node.start_mark)}); angiohull's files hold a few "
                               f"thousand: write the values out, or use fewer aliases")
            if depth > MAX_YAML_DEPTH:
                raise _Refused(f"nested more than {MAX_YAML_DEPTH} levels deep, its aliases (*name) expanded (the "
                               f"mapping or list at {_line(node.start_mark)}); angiohull's files need fewer than ten")
            continue
        if key in size:
            continue
        visiting.add(key)
        stack.append((node, True))
        for child in _children(node):
            if id(child) in visiting:
                raise _Refused(f"an alias at or after {_line(node.start_mark)} refers to a mapping or list that "
                               f"contains it (a recursive structure); angiohull's files hold plain trees of values")
            if id(child) not in size:
                stack.append((child, False))


def _decode(data: bytes, where: str, error: type[AngiohullError]) -> str:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        before = data[:exc.start]
        line = before.count(b"\n") + 1
        column = exc.start - (before.rfind(b"\n") + 1) + 1
        raise error(f"{where}: not UTF-8 text: byte 0x{data[exc.start]:02x} at line {line}, column {column} "
                    f"cannot be decoded; save the file as UTF-8") from None
    return text[1:] if text.startswith("\ufeff") else text


def load_yaml(source: Union[str, bytes], where: str, *, error: type[AngiohullError] = AngiohullError) -> Any:
    """Parse one YAML document with the checks of this module.

    Parameters
    ----------
    source : str or bytes
        The document (bytes must be UTF-8).
    where : str
        What to name in messages, usually the file's path.
    error : subclass of AngiohullError, keyword-only
        The error raised (e.g. ``StudyError`` for a study file).

    Returns
    -------
    object
        The document's data (dicts, lists, str, int, float, bool, None, dates), or None for an
        empty document.

    Raises
    ------
    AngiohullError
        As ``error``: invalid UTF-8, too large, invalid YAML (line and column), aliases that expand
        beyond :data:`MAX_YAML_NODES` values or into a recursive structure, nesting deeper than
        :data:`MAX_YAML_DEPTH`, or a duplicate key (the key and both lines).
    """
    size = len(source)
    if size > MAX_YAML_BYTES:
        raise error(f"{where}: the file is {size / 1048576:.1f} MiB; angiohull reads YAML files of at most "
                    f"{MAX_YAML_BYTES // 1048576} MiB (its study and experiment files take kilobytes)")
    text = _decode(source, where, error) if isinstance(source, bytes) else source
    try:
        loader = _StrictLoader(text)
    except yaml.YAMLError as exc:  # the reader refuses control characters as it starts
        raise error(f"{where}: invalid YAML: {' '.join(str(exc).split())}") from None
    try:
        return loader.get_single_data()
    except _Refused as exc:
        raise error(f"{where}: {exc.message}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        at = f" at {_line(mark)}" if mark is not None else ""
        context = f" ({exc.context})" if exc.context else ""
        problem = " ".join(str(exc.problem or exc).split())
        raise error(f"{where}: invalid YAML{at}: {problem}{context}") from None
    except yaml.YAMLError as exc:
        raise error(f"{where}: invalid YAML: {' '.join(str(exc).split())}") from None
    except RecursionError:  # pragma: no cover - the depth check comes first
        raise error(f"{where}: nested too deeply to read") from None
    finally:
        loader.dispose()


def read_yaml_file(path: Union[str, Path], *, error: type[AngiohullError] = AngiohullError,
                   what: str = "the file") -> Any:
    """Read and parse a YAML file with :func:`load_yaml` (``where`` is the path).

    Raises
    ------
    AngiohullError
        As ``error``, when the file cannot be read (naming ``what`` and the reason), or as
        :func:`load_yaml`.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > MAX_YAML_BYTES:
            raise error(f"{path}: the file is {size / 1048576:.1f} MiB; angiohull reads YAML files of at most "
                        f"{MAX_YAML_BYTES // 1048576} MiB (its study and experiment files take kilobytes)")
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror or exc})") from None
    return load_yaml(data, str(path), error=error)
