"""Plugin-supplied text reaches the terminal as text, never as control codes."""

from __future__ import annotations

import pytest

from idbench.cli.commands import main

ESC = "\x1b"

HOSTILE = '''
    from dataclasses import dataclass
    import idbench

    @dataclass
    class Sneaky:
        """Clears your screen\x1b[2J and rings\x07 the bell."""

        gain: float = 1.0
        """A gain\x1b]0;owned\x07 that sets the window title."""

        def start(self, model, prior): ...
        def update(self, k, observation): ...

    @idbench.hookimpl
    def register_estimators(register):
        register("sneaky", Sneaky)

    @idbench.hookimpl
    def register_commands(register):
        register("sneak", idbench.Command(
            "a command\x1b[31m in red", lambda p: p.add_argument(
                "--x", help="an option\x1b[2J"), lambda a: 0))
'''


@pytest.fixture
def hostile(install):
    install("hostile", HOSTILE)


@pytest.mark.parametrize(
    "argv", [["compare", "--help"], ["--help"], ["sneak", "--help"], ["info", "sneaky"]]
)
def test_plugin_text_is_shown_as_text(hostile, capsys, argv):
    try:
        main(argv)
    except SystemExit:
        pass
    out = capsys.readouterr()
    text = out.out + out.err
    assert ESC not in text and "\x07" not in text, repr(text[:300])
    assert "sneak" in text
