"""Settings from the environment, their hand-over to worker processes, and their documentation."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bonefit.cli import main
from bonefit.service.settings import Settings

ROOT = Path(__file__).resolve().parents[2]


def test_defaults_live_under_the_data_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for name in Settings.model_fields:
        monkeypatch.delenv(f"BONEFIT_{name.upper()}", raising=False)
    s = Settings(data_dir=tmp_path)
    assert s.resolved_database_url == f"sqlite:///{tmp_path.resolve()}/jobs.db"
    assert s.resolved_queue_url == f"sqlite:///{tmp_path.resolve()}/queue.db"
    assert s.resolved_storage_url == f"file://{tmp_path.resolve()}/artifacts"
    assert (s.max_upload_bytes, s.lease_seconds, s.max_attempts, s.workers) == (2**31, 30, 3, 2)
    assert s.api_keys == {}


def test_environment_is_read_and_round_trips(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BONEFIT_API_KEYS", json.dumps({"k1": "a", "k2": "b"}))
    monkeypatch.setenv("BONEFIT_LEASE_SECONDS", "3")
    monkeypatch.setenv("BONEFIT_S3_SECRET_ACCESS_KEY", "s3cr3t")
    monkeypatch.setenv("BONEFIT_METRICS_TOKEN", "scr4pe")
    monkeypatch.setenv("BONEFIT_QUEUE_URL", "redis://localhost:6379/1")
    s = Settings()
    assert s.api_keys == {"k1": "a", "k2": "b"}
    assert s.lease_seconds == 3
    assert "s3cr3t" not in repr(s)
    assert "scr4pe" not in repr(s)
    env = s.to_env()
    assert env["BONEFIT_S3_SECRET_ACCESS_KEY"] == "s3cr3t"
    assert env["BONEFIT_METRICS_TOKEN"] == "scr4pe"  # the workers' environment
    for name in list(Settings.model_fields):
        monkeypatch.delenv(f"BONEFIT_{name.upper()}", raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    assert Settings() == s.model_copy(update={"data_dir": s.data_dir.resolve()})


def test_every_setting_is_documented() -> None:
    doc = (ROOT / "docs" / "service.md").read_text()
    missing = [n for n in Settings.model_fields if f"`BONEFIT_{n.upper()}`" not in doc]
    assert not missing


def test_cli_has_serve_and_worker(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("serve", "worker"):
        with pytest.raises(SystemExit) as exit_:
            main([command, "--help"])
        assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert "--no-worker" in out
    assert "--concurrency" in out


def test_bad_settings_are_one_line_errors(monkeypatch: pytest.MonkeyPatch,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("BONEFIT_API_KEYS", "not json")
    assert main(["serve", "--port", "1"]) == 2
    assert capsys.readouterr().err.strip() == (
        "bonefit: error: cannot parse BONEFIT_API_KEYS: expected JSON")
    monkeypatch.delenv("BONEFIT_API_KEYS")
    monkeypatch.setenv("BONEFIT_LEASE_SECONDS", "-1")
    assert main(["worker"]) == 2
    assert "BONEFIT_LEASE_SECONDS" in capsys.readouterr().err
