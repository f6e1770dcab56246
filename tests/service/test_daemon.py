"""The service process's own settings: the interpreter's switch interval it serves with."""

from __future__ import annotations

import sys

import pytest

from service.daemon import Daemon
from service.settings import Settings


def test_serve_runs_at_the_settings_switch_interval_and_restores_the_one_before(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen: list[float] = []

    class Probe(Daemon):
        def _serve_http(self, announce: bool) -> None:
            seen.append(sys.getswitchinterval())

    before = sys.getswitchinterval()
    assert Settings().interpreter_switch_ms == 1.0  # the default, five times shorter than Python's
    monkeypatch.setenv("BODYHEALTH_INTERPRETER_SWITCH_MS", "2.5")
    assert Probe(Settings(database_url="sqlite://")).serve(announce=False) == 0
    assert seen == [pytest.approx(0.0025)] and sys.getswitchinterval() == before

    class Fails(Daemon):
        def _serve_http(self, announce: bool) -> None:
            raise SystemExit(3)  # as uvicorn does when it cannot bind

    assert Fails(Settings(database_url="sqlite://")).serve(announce=False) == 3
    assert sys.getswitchinterval() == before
    monkeypatch.setenv("BODYHEALTH_INTERPRETER_SWITCH_MS", "0")
    with pytest.raises(ValueError, match="interpreter_switch_ms"):
        Settings()
