"""petsoft/formats.md stays true: every TOML example in it is a valid experiment for petsoft's
reader, and every key the reader accepts at the top level is documented."""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np
import pytest

import petsoft
from petsoft.experiment import load_experiment

DOC = Path(petsoft.__file__).parent / "formats.md"
BLOCKS = re.findall(r"```toml\n(.*?)```", DOC.read_text(), flags=re.S)


def test_the_document_is_installed_with_the_package_and_has_examples():
    assert DOC.is_file()
    assert len(BLOCKS) >= 3


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_every_toml_example_loads(index, tmp_path):
    text = BLOCKS[index]
    if 'file = "pendulum.msh"' in text:
        # the mass-spring example's line mesh: two nodes, one spring, the bob at z = -1
        meshio.write(tmp_path / "pendulum.msh",
                     meshio.Mesh(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),
                                 [("line", np.array([[0, 1]]))]),
                     file_format="gmsh22", binary=False)
    path = tmp_path / "experiment.toml"
    path.write_text(text)
    experiment = load_experiment(path)
    assert experiment is not None


def test_every_top_level_section_is_documented():
    from petsoft.experiment.reader import TOP_KEYS

    documented = set(re.findall(r"^\[\[?([a-z_]+)", "\n".join(BLOCKS), flags=re.M))
    documented |= set(re.findall(r"^([a-z_]+) =", "\n".join(BLOCKS), flags=re.M))
    missing = set(TOP_KEYS) - documented
    assert not missing, f"sections the reader accepts but formats.md never shows: {missing}"
