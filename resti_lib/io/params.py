"""Reading a params file: plain YAML values only, a size limit checked before reading.

The one reader of params files (``resti run``, the stages' params, ``resti reoption --params``,
``resti measure --params``). What the keys and values may be (known keys, types, ranges) is checked
against the defaults by :func:`resti_lib.defaults.check_params`.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from .. import paths
from ..errors import InputError
from .files import read_text

MAX_PARAMS_BYTES = 1_000_000  # a params file over this size is refused before it is read
MAX_PARAMS_NODES = 100_000  # values in a params file once aliases are expanded (a YAML bomb is refused)

PLAIN_TAGS = {
    "tag:yaml.org,2002:str": "str", "tag:yaml.org,2002:int": "int", "tag:yaml.org,2002:float": "float",
    "tag:yaml.org,2002:bool": "bool", "tag:yaml.org,2002:null": "null", "tag:yaml.org,2002:seq": "list",
    "tag:yaml.org,2002:map": "dict", "tag:yaml.org,2002:merge": "merge key",
}
_KEY_TAGS = {"tag:yaml.org,2002:str", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float",
             "tag:yaml.org,2002:bool", "tag:yaml.org,2002:null", "tag:yaml.org,2002:merge"}


def _tag_name(tag: str) -> str:
    return tag.replace("tag:yaml.org,2002:", "!!")




def _check_plain(node, path: Path, key: str, budget: list) -> None:
    """Refuse every node of a YAML tree whose tag is not a plain type (one message: file, key, line),
    and trees that expand (through aliases) to more than :data:`MAX_PARAMS_NODES` values."""
    budget[0] -= 1
    if budget[0] < 0:
        raise InputError(f"more than {MAX_PARAMS_NODES} values once aliases are expanded (recursive or "
                         "exploding anchors?)", file=path, field=key or "(top level)")
    line = node.start_mark.line + 1
    if node.tag not in PLAIN_TAGS:
        raise InputError(f"value of type {_tag_name(node.tag)} at line {line} is not allowed; params values "
                         "are plain YAML: text, numbers, true/false, null, lists and mappings (quote dates "
                         "and other text)", file=path, field=key or "(top level)")
    if isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _check_plain(item, path, f"{key}[{i}]", budget)
    elif isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            name = str(k.value) if isinstance(k, yaml.ScalarNode) else "?"
            if k.tag not in _KEY_TAGS:
                raise InputError(f"key of type {_tag_name(k.tag)} at line {k.start_mark.line + 1} is not "
                                 "allowed; params keys are plain text", file=path, field=key or "(top level)")
            _check_plain(v, path, f"{key}.{name}" if key else name, budget)


def read_params(path: str | Path) -> dict:
    """Read a params YAML file (an empty file is refused).

    Values are restricted to plain YAML types (str, int, float, bool, null, list, dict); any other
    type is refused with one line naming the file, the key and the line. A missing file, a file over
    :data:`MAX_PARAMS_BYTES` (refused before it is read), a file that is not UTF-8 or not valid
    YAML, or a top level that is not a mapping is an :class:`InputError`. What the keys and values
    may be is :func:`resti_lib.defaults.check_params`'.
    """
    path = paths.resolve(path)
    if not path.exists():
        raise InputError("params file not found", file=path)
    size = path.stat().st_size if path.is_file() else 0
    if size > MAX_PARAMS_BYTES:  # refused before it is read, let alone parsed
        raise InputError(f"params file of {size:,} bytes; params files are at most {MAX_PARAMS_BYTES:,} bytes",
                         file=path)
    text = read_text(path)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise InputError(f"not valid YAML{where}: {problem}", file=path) from None
    if node is None:
        raise InputError("the params file is empty: nothing would be set, and the defaults would run "
                         "unnoticed in its place", file=path)
    _check_plain(node, path, "", [MAX_PARAMS_NODES])
    try:
        data = yaml.load(text, Loader=yaml.SafeLoader)
    except (yaml.YAMLError, RecursionError, ValueError, OverflowError) as e:
        raise InputError(f"cannot read the YAML values ({' '.join(str(e).split())[:200]})", file=path) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise InputError(f"params must be a mapping of names to values, got a {type(data).__name__}", file=path)
    return data




__all__ = ["MAX_PARAMS_BYTES", "MAX_PARAMS_NODES", "read_params"]
