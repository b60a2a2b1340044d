"""Execute parameterised notebooks with papermill and render them to HTML.

Parameters come from ``params/*.yaml``; names are checked against the notebook's ``parameters``
cell before execution (papermill itself only warns on an unknown name). A failing cell raises
:class:`NotebookError` naming the notebook and the cell, so ``make report`` exits non-zero.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import yaml

from . import paths
from .errors import InputError, NotebookError

KERNEL = "python3"


@dataclass
class NotebookRun:
    name: str
    executed: Path
    html: Path | None
    seconds: float


# The YAML types a params value may have: exactly the types papermill writes into a notebook as
# literals. Any other tag (``!!binary``, ``!!timestamp`` and plain dates, ``!!set``, ``!!omap``,
# ``!!pairs``, ``!!python/...``, custom tags) is refused before it is constructed, so a params file
# can never become code in a notebook.
PLAIN_TAGS = {
    "tag:yaml.org,2002:str": "str", "tag:yaml.org,2002:int": "int", "tag:yaml.org,2002:float": "float",
    "tag:yaml.org,2002:bool": "bool", "tag:yaml.org,2002:null": "null", "tag:yaml.org,2002:seq": "list",
    "tag:yaml.org,2002:map": "dict", "tag:yaml.org,2002:merge": "merge key",
}
_KEY_TAGS = {"tag:yaml.org,2002:str", "tag:yaml.org,2002:int", "tag:yaml.org,2002:float",
             "tag:yaml.org,2002:bool", "tag:yaml.org,2002:null", "tag:yaml.org,2002:merge"}


def _tag_name(tag: str) -> str:
    return tag.replace("tag:yaml.org,2002:", "!!")


MAX_PARAMS_NODES = 100_000  # values in a params file once aliases are expanded (a YAML bomb is refused)


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


def load_params(path: str | Path) -> dict:
    """Read a params YAML file (an empty file is an empty dict).

    Values are restricted to plain YAML types (str, int, float, bool, null, list, dict); any other
    type is refused with one line naming the file, the key and the line. A missing file, a file
    that is not UTF-8 or not valid YAML, or a top level that is not a mapping is an
    :class:`InputError`.
    """
    from .io.files import read_text

    path = paths.resolve(path)
    if not path.exists():
        raise InputError("params file not found", file=path)
    text = read_text(path)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise InputError(f"not valid YAML{where}: {problem}", file=path) from None
    if node is None:
        return {}
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


def notebook_parameters(nb_path: Path) -> dict:
    """Names and defaults of the notebook's ``parameters`` cell."""
    import papermill

    return papermill.inspect_notebook(str(nb_path))


def check_parameters(nb_path: Path, params: dict) -> None:
    known = notebook_parameters(nb_path)
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise NotebookError(f"{nb_path.name}: unknown parameter(s) {unknown}; the parameters cell "
                            f"declares {sorted(known)}")


def _failing_cell(executed: Path) -> str:
    try:
        nb = json.loads(executed.read_text(encoding="utf-8"))
    except Exception:
        return "unknown cell"
    code_idx = 0
    for cell in nb.get("cells", []):
        if cell.get("cell_type") != "code":
            continue
        code_idx += 1
        for out in cell.get("outputs", []):
            if out.get("output_type") == "error":
                src = "".join(cell.get("source", "")).strip().splitlines()
                first = src[0] if src else ""
                return f"code cell {code_idx} ({first[:70]!r}): {out.get('ename')}: {out.get('evalue')}"
    return "unknown cell"


def render_html(executed: Path, html_path: Path) -> Path:
    from nbconvert import HTMLExporter

    exporter = HTMLExporter()
    exporter.exclude_input_prompt = True
    exporter.exclude_output_prompt = True
    body, _ = exporter.from_filename(str(executed))
    html_path.parent.mkdir(parents=True, exist_ok=True)
    html_path.write_text(body, encoding="utf-8")
    return html_path


def run_notebook(nb_path: str | Path, params: dict, *, out_dir: Path | None = None,
                 html_dir: Path | None = None, progress: bool = False) -> NotebookRun:
    """Execute one notebook with papermill (kernel ``python3``, working directory = repo root)."""
    import papermill
    from papermill.exceptions import PapermillExecutionError

    nb_path = Path(nb_path)
    out_dir = out_dir or paths.OUTPUTS / "notebooks"
    html_dir = html_dir or paths.OUTPUTS / "report" / "notebooks"
    out_dir.mkdir(parents=True, exist_ok=True)
    check_parameters(nb_path, params)
    executed = out_dir / nb_path.name
    t0 = time.perf_counter()
    try:
        papermill.execute_notebook(str(nb_path), str(executed), parameters=params, kernel_name=KERNEL,
                                   cwd=str(paths.ROOT), progress_bar=progress, log_output=False)
    except PapermillExecutionError as e:
        raise NotebookError(f"notebook {nb_path.name} failed in {_failing_cell(executed)} "
                            f"(executed copy: {executed})") from e
    seconds = time.perf_counter() - t0
    html = render_html(executed, html_dir / (nb_path.stem + ".html"))
    return NotebookRun(nb_path.stem, executed, html, seconds)


def strip_outputs(nb_paths: list[str]) -> None:
    """Remove outputs and execution counts from notebooks (they are committed clean)."""
    import nbformat

    for p in nb_paths:
        nb = nbformat.read(p, as_version=4)
        for c in nb.cells:
            if c.cell_type == "code":
                c.outputs = []
                c.execution_count = None
            c.metadata.pop("execution", None)
            c.metadata.pop("papermill", None)
        nb.metadata.pop("papermill", None)
        nbformat.write(nb, p)


if __name__ == "__main__":  # python -m resti_lib.runner --strip notebooks/*.ipynb
    if len(sys.argv) > 2 and sys.argv[1] == "--strip":
        strip_outputs(sys.argv[2:])
