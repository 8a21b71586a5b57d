"""``idbench check BODY.toml``: the body on each of its meshes, or one line a problem.

The synthetic organ's body (150 and 1,200 nodes); copies with a marker
inside the body, an unknown region and an unreadable legacy mesh.
"""

from __future__ import annotations

import pytest
from support.helpers import ORGAN_BODY, organ_body

from idbench.cli.commands import main


@pytest.fixture(scope="module")
def body(tmp_path_factory):
    return organ_body(tmp_path_factory.mktemp("organ"))


def tables(out: str) -> dict[str, list[str]]:
    """The printed tables by the first word of their title."""
    found: dict[str, list[str]] = {}
    for block in out.strip().split("\n\n"):
        lines = block.splitlines()
        found[lines[0].split()[0].rstrip(":")] = lines
    return found


def test_a_good_body_prints_its_tables_and_exits_0(body, capsys):
    assert main(["check", str(body)]) == 0
    out = capsys.readouterr().out
    shown = tables(out)
    meshes = shown[str(body)]
    assert meshes[1].split()[:4] == ["mesh", "nodes", "tets", "min"]
    assert meshes[3].startswith("organ-n150") and "(truth)" in meshes[4]
    loads = [line.split() for line in shown["loads"][3:]]
    push = {r[3]: r for r in loads if r[0] == "push"}
    kept = {r[3]: r for r in loads if r[0] == "push-conserved"}
    assert float(push["organ-n150"][7]) < 0.9  # resultant / truth
    assert kept["organ-n150"][7] == "1.0000" and float(kept["organ-n150"][10]) > 1.1
    assert push["organ-n1200"][7] == "1.0000"
    markers = shown["markers"]
    assert [r.split()[0] for r in markers[3:]] == ["1", "2", "3"]
    assert "1 lesion" in "\n".join(shown["targets"])
    notes = [line for line in out.splitlines() if line.startswith("note: ")]
    assert any(n.startswith("note: push on organ-n150") and "conserve" in n
               for n in notes)  # fmt: skip


def test_a_marker_inside_the_body_is_a_problem_naming_mesh_and_marker(
    body, tmp_path, capsys
):
    (tmp_path / "meshes").symlink_to(body.parent / "meshes")
    bad = ORGAN_BODY.replace("[0.0, 0.0, 0.03]", "[0.0, 0.0, 0.0]")
    (tmp_path / "bad.toml").write_text(bad)
    assert main(["check", str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "[markers] point 2 at [0.0, 0.0, 0.0] is inside the body" in err[0]
    assert "organ-n1200.msh" in err[0] and "nodes)" in err[0]
    assert "snap_distance = 0.005 m (the default)" in err[0]


def test_each_problem_is_one_line(body, tmp_path, capsys):
    (tmp_path / "meshes").symlink_to(body.parent / "meshes")
    bad = ORGAN_BODY.replace(
        'half_space = { point = [-0.045, 0.0, 0.0], normal = [-1.0, 0.0, 0.0] }',
        'name = "ligament"',
    ).replace("lesion = [0.02, 0.0, 0.0]", "lesion = [0.2, 0.0, 0.0]")
    (tmp_path / "bad.toml").write_text(bad)
    assert main(["check", str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    fixed = [e for e in err if "[fixed] region 'ligament' is not in mesh" in e]
    assert len(fixed) == 2  # one per mesh, each named with its node count
    assert all("organ-n" in e and "nodes); its regions are surface, volume" in e
               for e in fixed)  # fmt: skip
    assert any("[targets] lesion (target 1) at [0.2, 0.0, 0.0] lies outside" in e
               for e in err)  # fmt: skip


def test_a_legacy_gmsh_mesh_suggests_its_conversion(tmp_path, capsys):
    legacy = tmp_path / "old.msh"
    legacy.write_text("$NOD\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$ENDNOD\n"
                      "$ELM\n1\n1 4 1 1 4 1 2 3 4\n$ENDELM\n")  # fmt: skip
    body = ORGAN_BODY.replace('truth = "meshes/organ-n1200.msh"', 'truth = "old.msh"')
    (tmp_path / "body.toml").write_text(body.replace(
        'models = ["meshes/organ-n150.msh"]', "models = []"))  # fmt: skip
    assert main(["check", str(tmp_path / "body.toml")]) == 2
    err = capsys.readouterr().err
    assert "legacy gmsh v1 mesh" in err and "-save -format msh22 -o" in err
