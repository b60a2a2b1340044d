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


def load_params(path: str | Path) -> dict:
    """Read a params YAML file (an empty file is an empty dict)."""
    path = paths.resolve(path)
    if not path.exists():
        raise FileNotFoundError(f"params file not found: {path}")
    with open(path, encoding="utf-8") as f:
        data = yaml.safe_load(f) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: params must be a mapping, got {type(data).__name__}")
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
