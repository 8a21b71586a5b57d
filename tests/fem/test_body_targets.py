"""A body's hidden targets lie inside it: one outside is refused, not projected."""

from __future__ import annotations

import pytest
from support.bodies import write_beam_body

from idbench.cli.commands import main


def compare(body, tmp_path) -> list[str]:
    mesh = str(tmp_path / "beam-6x2x2.vtu")
    return ["compare", "--model", "solid", "--model-option", f"body={body}",
            "--truth-mesh", mesh, "--meshes", mesh, "--scenarios", "end",
            "--steps", "2", "--seeds", "1", "--estimators", "rls",
            "--out", str(tmp_path / "out"), "-q"]  # fmt: skip


def with_targets(tmp_path, targets: str):
    body, beam = write_beam_body(tmp_path, spec="6x2x2")
    body.write_text(body.read_text() + f"[targets]\n{targets}\n")
    return body, beam


@pytest.mark.parametrize(
    ("targets", "words"),
    [
        ("tumour = [0.1, 0.015, 0.045]",
         ["target 1 ('tumour') at [0.1, 0.015, 0.045] lies outside the body",
          "0.015 m from the surface of", "beam-6x2x2.vtu"]),
        ("tumour = [0.1, 0.015, 0.015]\nvessel = [[0.05, 0.01, 0.01], "
         "[0.05, -0.002, 0.01]]",
         ["target 3 ('vessel[1]') at [0.05, -0.002, 0.01] lies outside",
          "0.002 m from"]),
    ],
)  # fmt: skip
def test_a_target_outside_the_body_is_one_line(tmp_path, capsys, targets, words):
    body, _ = with_targets(tmp_path, targets)
    assert main(compare(body, tmp_path)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for w in words:
        assert w in err, err
    assert not (tmp_path / "out").exists()


def test_targets_inside_the_body_run(tmp_path, capsys):
    body, _ = with_targets(tmp_path, "tumour = [0.1, 0.015, 0.015]")
    assert main(compare(body, tmp_path)) == 0
