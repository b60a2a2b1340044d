"""The notebook runner keeps the kernel process's own output apart from ours, and quotes it only
when the kernel fails."""

from __future__ import annotations

import nbformat
import pytest

from resti_lib.errors import NotebookError
from resti_lib.run.notebooks import run_notebook


def _notebook(path, *sources):
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell("x = 1", metadata={"tags": ["parameters"]})]
    nb.cells += [nbformat.v4.new_code_cell(src) for src in sources]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.write(nb, path)
    return path


def test_the_kernels_own_output_does_not_reach_ours(tmp_path, capfd):
    # writes to the process's file descriptors bypass the notebook's channels, as the kernel's log does
    nb = _notebook(tmp_path / "noisy.ipynb",
                   "import os\nos.write(2, b'KERNEL-STDERR-MARK\\n'); os.write(1, b'KERNEL-STDOUT-MARK\\n')\n"
                   "print('CELL-OUTPUT-MARK')")
    r = run_notebook(nb, {"x": 2}, out_dir=tmp_path / "exec", html_dir=tmp_path / "html")
    out, err = capfd.readouterr()
    assert "KERNEL-STDERR-MARK" not in err + out and "KERNEL-STDOUT-MARK" not in err + out
    executed = nbformat.read(r.executed, as_version=4)
    printed = "".join(o.get("text", "") for c in executed.cells if c.cell_type == "code" for o in c.outputs)
    assert "CELL-OUTPUT-MARK" in printed  # the notebook's own output is where it always was
    assert r.html.is_file()


def test_a_dead_kernel_is_reported_with_its_last_output(tmp_path, capfd):
    nb = _notebook(tmp_path / "dies.ipynb",
                   "import os\nos.write(2, b'first line\\nLAST-WORDS-MARK\\n'); os._exit(3)")
    with pytest.raises(NotebookError) as info:
        run_notebook(nb, {}, out_dir=tmp_path / "exec", html_dir=tmp_path / "html")
    msg = str(info.value)
    assert msg.startswith("notebook dies.ipynb: the kernel failed") and "LAST-WORDS-MARK" in msg, msg
    assert "LAST-WORDS-MARK" not in "".join(capfd.readouterr())
