"""A small body with an offline design, for the reduced-model tests."""

from __future__ import annotations

from support.bodies import write_beam_body

DESIGN_TRACTIONS = (
    ("d-y", (1.0, -8.9, 1.8)),
    ("d-z", (1.0, 1.8, -8.9)),
    ("d-x", (250.0, 1.8, 1.8)),
    ("d-yb", (-0.5, -8.9, -1.8)),
    ("d-zb", (-0.5, -1.8, -8.9)),
)
"""End tractions (Pa) of the design: none is the body's own ``end`` (0, -8.9, 0)."""


def write_designed_beam(tmp_path, spec="8x2x2", law="svk", steps=6,
                        moduli=(2500.0, 20000.0), extra=""):  # fmt: skip
    """The beam body of :func:`write_beam_body` with a ``[design]`` table."""
    body, beam = write_beam_body(tmp_path, spec, law=law)
    x1 = float(beam.upper[0])
    eps = 1e-9
    region = (
        f"{{ box = {{ lower = [{x1 - eps}, -1, -1], upper = [{x1 + eps}, 1, 1] }} }}"
    )
    text = f"""
[design]
moduli = {{ E = [{moduli[0]}, {moduli[1]}] }}
steps = {steps}
{extra}
"""
    for name, t in DESIGN_TRACTIONS:
        text += f"""
[[design.manipulation]]
name = "{name}"
kind = "traction"
region = {region}
traction = {list(t)}
"""
    body.write_text(body.read_text() + text)
    return body, beam
