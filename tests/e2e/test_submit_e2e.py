"""`bonefit submit`: a batch of 20 takes (one broken) against a real embedded server, then the
same command again: only the broken take is tried again."""

from __future__ import annotations

import hashlib
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from bonefit.client import Client
from bonefit.estimation.vocabulary import RESULT_FORMATS
from tests.e2e.conftest import BONEFIT, Launcher, ServerProcess, clean_env

pytestmark = pytest.mark.slow
GOOD = 19


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    launcher = Launcher(tmp_path_factory)
    yield launcher.server({"BONEFIT_API_KEYS": '{"batch-key": "studio-b"}',
                           "BONEFIT_WORKERS": "2"})
    launcher.close()


def make_takes(folder: Path) -> list[Path]:
    """19 tiny synthetic sensor recordings (90 frames) and a copy of one with a bad value
    (the upload passes its sniff; the job fails naming the line)."""
    from bonefit.estimation.io.sensors import write_sensor_csv
    from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

    folder.mkdir()
    takes = []
    for seed in range(GOOD):
        rec, _ = simulate_sensors(example_motion(n_frames=90, fps=60.0, seed=seed),
                                  units_m=0.01, seed=seed)
        path = folder / f"take{seed:02d}.csv"
        write_sensor_csv(rec, path)
        takes.append(path)
    lines = takes[7].read_text().splitlines()
    row = next(i for i, line in enumerate(lines) if line.startswith("time")) + 20
    lines[row] = lines[row].replace(",", ",abc,", 1)  # one value that is not a number
    broken = folder / "take07-broken.csv"
    broken.write_text("\n".join(lines) + "\n")
    takes.insert(7, broken)
    return takes


def row_of_bad_value(path: Path) -> int:
    """The 1-based line number of the ``abc`` value."""
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if "abc" in line)


def submit(server: ServerProcess, takes: list[Path], outdir: Path
           ) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BONEFIT), "submit", *map(str, takes), "--server", server.base_url, "--kind",
         "skeleton", "--param", "method=auto", "--jobs", "4", "-o", str(outdir)],
        env=clean_env({"BONEFIT_API_KEY": "batch-key"}), capture_output=True, text=True,
        timeout=600)


def test_a_batch_with_a_broken_take_then_a_resume(server: ServerProcess, tmp_path: Path) -> None:
    takes = make_takes(tmp_path / "takes")
    out = tmp_path / "out"
    first = submit(server, takes, out)
    assert first.returncode == 1, first.stdout + first.stderr
    for take in takes:
        results = sorted(p.name for p in out.glob(f"{take.stem}.*"))
        expected = [] if "broken" in take.name else sorted(f"{take.stem}.{f}"
                                                           for f in RESULT_FORMATS)
        assert results == expected
    assert (out / "take03.bvh").read_text().startswith("HIERARCHY")
    broken_line = next(line for line in first.stdout.splitlines()
                       if line.startswith("take07-broken.csv"))
    assert "failed" in broken_line
    assert "job failed" in broken_line, broken_line
    assert f"line {row_of_bad_value(takes[7])}" in broken_line, broken_line
    assert f"{GOOD} done, 0 already done, 1 failed" in first.stdout

    with Client(server.base_url, "batch-key") as client:
        jobs_before = client.jobs(limit=1000)
        recordings_before = client.request("GET", "/v1/recordings?limit=1000").json()["items"]
        (out / "take05.json").unlink()  # a lost result file is fetched again, not recomputed
        second = submit(server, takes, out)
        jobs_after = client.jobs(limit=1000)
        recordings_after = client.request("GET", "/v1/recordings?limit=1000").json()["items"]
    assert second.returncode == 1, second.stdout + second.stderr
    assert f"0 done, {GOOD} already done, 1 failed" in second.stdout
    assert len(jobs_before) == GOOD + 1
    new = [j for j in jobs_after if j.id not in {b.id for b in jobs_before}]
    assert len(new) == 1, new  # only the broken take was submitted again...
    assert new[0].status == "failed"
    assert len(recordings_after) == len(recordings_before) + 1  # ...and uploaded again
    broken_sha = next(r["sha256"] for r in recordings_after if r["id"] == new[0].recording_id)
    assert broken_sha == hashlib.sha256(takes[7].read_bytes()).hexdigest()
    assert (out / "take05.json").is_file()
