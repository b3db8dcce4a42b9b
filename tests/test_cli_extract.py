"""``btel extract``: its output is a .npy matrix, and its help lists what --param can set."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from btel.cli import main
from btel.descriptors import get_descriptor


@pytest.mark.parametrize("name", ["gp_ref.csv", "gp_ref.npz", "gp_ref"])
def test_an_output_that_is_not_npy_is_refused(tmp_path: Path, name: str) -> None:
    (tmp_path / "images").mkdir()
    result = CliRunner().invoke(main, ["extract", str(tmp_path / "images"), "-o", str(tmp_path / name)])
    assert result.exit_code == 2, result.output
    assert "writes a descriptor matrix (.npy)" in result.output
    assert f"name it e.g. {tmp_path / 'gp_ref.npy'}" in result.output and not (tmp_path / name).exists()


@pytest.mark.parametrize("descriptor", ["hog", "patchnorm", "densevlad"])
def test_help_lists_every_descriptor_parameter(descriptor: str) -> None:
    help_text = " ".join(CliRunner().invoke(main, ["extract", "--help"]).output.split())
    assert "btel methods --params" not in help_text  # it lists methods, not descriptors
    listed = help_text.split("Parameters: ", 1)[1].split(f"{descriptor}: ", 1)[1].split(";")[0]
    for name in set(get_descriptor(descriptor).get_params()) - {"size"}:  # size: --size
        assert name in listed, (descriptor, name)
