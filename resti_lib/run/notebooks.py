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

from .. import paths
from ..errors import NotebookError
from ..io.params import read_params

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
#: Error types that, raised inside a notebook, mean bad input (``resti run`` exits 2 with their line).
INPUT_ERRORS = frozenset({"InputError", "SourceError", "SourceGapError", "OutputError"})


def load_params(path: str | Path) -> dict:
    """A params YAML file (:func:`resti_lib.io.params.read_params`: plain values, size limit)."""
    return read_params(path)


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


# The rendered page: JupyterLab's look without the scripts it loads from the network (require.js,
# MathJax, Mermaid: nothing in our notebooks needs them), so a page opens offline, plus a link back
# to the report index (pages live in report/notebooks/, the index in report/).
_HTML_TEMPLATE = """{%- extends 'index.html.j2' -%}
{%- block html_head_js_requirejs -%}{%- endblock html_head_js_requirejs -%}
{%- block html_head_js_mathjax -%}{%- endblock html_head_js_mathjax -%}
{%- block html_head_js_mermaidjs -%}{%- endblock html_head_js_mermaidjs -%}
{% block extra_css %}<style>
.resti-nav{max-width:1100px;margin:0 auto;padding:.6em 1em;font-family:system-ui,sans-serif;font-size:14px}
.resti-nav a{color:#1a5e9a}
.jp-RenderedImage img{max-width:100%;height:auto}
</style>{% endblock extra_css %}
{%- block body_header -%}{{ super() }}
<nav class="resti-nav"><a href="../index.html">&larr; resti audit report (index)</a></nav>
{%- endblock body_header -%}
"""


def render_html(executed: Path, html_path: Path) -> Path:
    """Render an executed notebook to a self-contained HTML page (no network resources), linking back
    to the report index."""
    from jinja2 import DictLoader
    from nbconvert import HTMLExporter

    from ..io.files import atomic_write_bytes

    exporter = HTMLExporter(template_name="lab", extra_loaders=[DictLoader({"resti.html.j2": _HTML_TEMPLATE})],
                            template_file="resti.html.j2")
    exporter.exclude_input_prompt = True
    exporter.exclude_output_prompt = True
    body, _ = exporter.from_filename(str(executed))
    atomic_write_bytes(html_path, body.encode("utf-8"))
    return html_path


# Kernel settings for executed notebooks: its log at CRITICAL (the kernel warns on every start that
# it talks over local TCP, and logs the interrupt of its own shutdown; that log goes to the kernel's
# own file, see _kernel_manager_writing_to, and routine lines would crowd out the ones quoted when it
# fails), and tables displayed as the report shows them (no index column, shares as percentages:
# resti_lib.io.tables.install_display).
KERNEL_ARGUMENTS = ["--IPKernelApp.log_level=CRITICAL",
                    "--IPKernelApp.exec_lines=import resti_lib.io.tables as _rt; _rt.install_display()"]


KERNEL_LOG_TAIL = 1500  # characters of the kernel's own output quoted when the kernel fails


def _kernel_manager_writing_to(sink):
    """A kernel manager class whose kernel process writes its own stdout and stderr to ``sink``.

    The kernel's process output is not the notebook's output (that travels over the kernel's
    channels into the executed notebook). It is the kernel's log: start-up notices, and races of its
    own shutdown that it reports as tracebacks although the notebook ran to the end. Inherited, it
    would land in the middle of ``resti run``'s progress bar; kept apart, it is quoted only when the
    kernel fails."""
    from jupyter_client.manager import AsyncKernelManager

    class _Manager(AsyncKernelManager):
        async def start_kernel(self, **kw):
            kw.update(stdout=sink, stderr=sink)
            return await super().start_kernel(**kw)

    return _Manager


def _tail(sink, lines: int = 8) -> str:
    """The last ``lines`` non-blank lines the kernel process wrote (at most :data:`KERNEL_LOG_TAIL`
    characters)."""
    sink.flush()
    sink.seek(0)
    kept = [ln.rstrip() for ln in sink.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    return "\n".join(kept[-lines:])[-KERNEL_LOG_TAIL:]


def run_notebook(nb_path: str | Path, params: dict, *, out_dir: Path | None = None,
                 html_dir: Path | None = None, progress: bool = False) -> NotebookRun:
    """Execute one notebook with papermill (kernel ``python3``, working directory = repo root).

    The kernel process's own output goes to an unnamed temporary file (see
    :func:`_kernel_manager_writing_to`); its last lines are part of the error when the kernel fails."""
    import tempfile

    import papermill
    from papermill.exceptions import PapermillExecutionError

    nb_path = Path(nb_path)
    out_dir = out_dir or paths.OUTPUTS / "notebooks"
    html_dir = html_dir or paths.OUTPUTS / "report" / "notebooks"
    out_dir.mkdir(parents=True, exist_ok=True)
    check_parameters(nb_path, params)
    executed = out_dir / nb_path.name
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as sink:
        try:
            papermill.execute_notebook(str(nb_path), str(executed), parameters=params, kernel_name=KERNEL,
                                       cwd=str(paths.ROOT), progress_bar=progress, log_output=False,
                                       extra_arguments=list(KERNEL_ARGUMENTS),
                                       kernel_manager_class=_kernel_manager_writing_to(sink))
        except PapermillExecutionError as e:
            err = NotebookError(f"notebook {nb_path.name} failed in {_failing_cell(executed)} "
                                f"(executed copy: {executed})")
            if e.ename in INPUT_ERRORS:  # bad input found inside the notebook: the run reports it as input
                err.input_message = " ".join(str(e.evalue).split())
            raise err from e
        except Exception as e:  # the kernel could not start, died or timed out
            first = (str(e).strip().splitlines() or [""])[0]
            log = _tail(sink)
            said = f"; the kernel's last output:\n{log}" if log else "; the kernel printed nothing"
            raise NotebookError(f"notebook {nb_path.name}: the kernel failed ({type(e).__name__}: {first}){said}") \
                from e
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


if __name__ == "__main__":  # python -m resti_lib.run.notebooks --strip notebooks/*.ipynb
    if len(sys.argv) > 2 and sys.argv[1] == "--strip":
        strip_outputs(sys.argv[2:])
