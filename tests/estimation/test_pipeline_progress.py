"""A pipeline run reports progress within every stage, reading and writing included, as one
non-decreasing fraction of the whole run (issue 19: the CLI's ETA and a job's progress).

A generated take read with small blocks (``CHUNK_CHARS`` lowered, so that a short take is
parsed in many blocks as a long one is) and written as JSON, BVH, CSV and NPZ. No timing is
asserted: only that every stage reports fractions strictly inside the run, in order.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from bonefit.estimation import pipeline
from bonefit.estimation.io import sensor_csv
from bonefit.estimation.io.sensors import write_sensor_csv
from bonefit.estimation.io.skeleton import read_skeleton_json
from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

STAGES = ("reading", "gaps", "slip", "torso", "limbs", "orientations", "writing")
FPS = 240.0


@pytest.fixture(scope="module")
def take(tmp_path_factory: pytest.TempPathFactory) -> Path:
    rec, _ = simulate_sensors(example_motion(2400, fps=FPS, seed=3), units_m=0.01,
                              n_sensors=15, seed=3, fps=FPS)
    path = tmp_path_factory.mktemp("take") / "take.csv"
    write_sensor_csv(rec, path)
    return path


def test_every_stage_reports_inside_the_run(take: Path, tmp_path: Path,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sensor_csv, "CHUNK_CHARS", 1 << 16)  # ~40 blocks of this take
    reports: list[tuple[float, str]] = []
    threads: set[int] = set()

    def record(fraction: float, stage: str) -> None:
        reports.append((fraction, stage))
        threads.add(threading.get_ident())

    files = {fmt: tmp_path / f"s.{fmt}" for fmt in ("json", "bvh", "csv", "npz")}
    outputs = pipeline.SkeletonOutputs(**files)
    run = pipeline.run_skeleton(pipeline.SensorSource(take), pipeline.SkeletonRunOptions(),
                                outputs, progress=record)
    fractions = [f for f, _ in reports]
    assert fractions == sorted(fractions)
    assert (reports[0], reports[-1]) == ((0.0, "reading"), (1.0, "writing"))
    stages = [s for _, s in reports]
    # each stage is one run of reports, in this order
    assert [s for k, s in enumerate(stages) if k == 0 or s != stages[k - 1]] == list(STAGES)
    for stage in STAGES:
        inside = {f for f, s in reports if s == stage and 0.0 < f < 1.0}
        assert len(inside) >= 3, (stage, sorted(inside))
    # from the caller's thread only (the BVH, CSV and NPZ are written in a second one)
    assert threads == {threading.get_ident()}
    # the read shares the run's first tenth, the writes its last fifth
    assert max(f for f, s in reports if s == "reading") <= pipeline.READ_SHARE
    assert min(f for f, s in reports if s == "writing") >= 1.0 - pipeline.WRITE_SHARE
    assert read_skeleton_json(files["json"]).n_frames == run.recording.n_frames == 2400
    assert all(files[fmt].stat().st_size > 0 for fmt in ("bvh", "csv", "npz"))
