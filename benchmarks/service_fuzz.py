"""Schemathesis against a real `bonefit serve`: no generated request may get a 5xx.

Schemathesis reads the served OpenAPI document and sends what it derives from it: valid and
invalid parameters, headers and bodies (coverage and fuzzing phases), sequences that follow
the links between operations (stateful phase), and methods each path does not have. Ids of a
seeded recording and job are offered half the time for the ids in paths and bodies, so that
requests also reach past the 404s. Two servers are fuzzed in turn: one with API keys (the
requests carry a key) and one without (loopback clients only, no key sent). Every request is
recorded (HAR); the numbers are counted from it, and the server's log is searched for
tracebacks.

    python benchmarks/service_fuzz.py                      # 2 servers x 2 seeds: 10,000+ requests
    python benchmarks/service_fuzz.py --max-examples 20 --seeds 1   # a quick look

`run_schemathesis` is also used by `tests/e2e/test_fuzz.py` for a bounded run.
"""

from __future__ import annotations

import argparse
import collections
import json
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "estimation" / "examples" / "walk.csv"
KEY = "fuzz-key"


@dataclass(frozen=True)
class Ids:
    """Resources that exist on the server: offered to the fuzzer for path and body ids."""

    recordings: tuple[str, ...]
    jobs: tuple[str, ...]
    deletable: tuple[str, ...] = ()


@dataclass
class FuzzRun:
    """What one schemathesis run sent and got."""

    requests: int
    statuses: collections.Counter[int]
    server_errors: list[str] = field(default_factory=list)
    exit_code: int = 0
    seconds: float = 0.0
    output: str = ""

    @property
    def ok(self) -> bool:
        """No 5xx, no failed check, no network error."""
        return not self.server_errors and self.exit_code == 0


def seed_ids(client: httpx.Client, deletable: int = 4) -> Ids:
    """Upload the example recording (and ``deletable`` more) and a cancelled job."""
    def upload() -> str:
        r = client.post("/v1/recordings", params={"filename": "walk.csv", "format": "sensor-csv"},
                        content=EXAMPLE.read_bytes())
        r.raise_for_status()
        rec_id: str = r.json()["id"]
        return rec_id

    rec = upload()
    job = client.post("/v1/jobs", json={"kind": "skeleton", "recording_id": rec})
    job.raise_for_status()
    job_id = job.json()["id"]
    client.post(f"/v1/jobs/{job_id}/cancel").raise_for_status()  # so /events on it ends
    return Ids(recordings=(rec,), jobs=(job_id,),
               deletable=tuple(upload() for _ in range(deletable)))


def worker_elsewhere(data_dir: Path) -> None:
    """A worker heartbeat in the server's job store, fresh for a day: /readyz answers 200
    without workers here running the fuzzer's jobs (`bonefit serve --no-worker`)."""
    from bonefit.service.sql_store import SqlJobStore

    store = SqlJobStore.from_url(f"sqlite:///{data_dir / 'jobs.db'}")
    try:
        store.beat_worker("fuzz:elsewhere", time.time() + 86400)
    finally:
        store.engine.dispose()


def write_config(directory: Path, ids: Ids) -> Path:
    """A schemathesis.toml offering ``ids`` half the time (DELETE gets its own, so the
    recordings the other operations use stay)."""
    def values(items: tuple[str, ...]) -> str:
        return json.dumps(list(items) or ["0"])

    text = f"""
[dictionaries.recordings]
values = {values(ids.recordings)}
[dictionaries.jobs]
values = {values(ids.jobs)}
[dictionaries.deletable]
values = {values(ids.deletable)}

[parameters]
"path.recording_id" = {{ dictionary = "recordings", probability = 0.5 }}
"path.job_id" = {{ dictionary = "jobs", probability = 0.5 }}
"body.recording_id" = {{ dictionary = "recordings", probability = 0.5 }}

[[operations]]
include-method = "DELETE"
parameters = {{ "path.recording_id" = {{ dictionary = "deletable", probability = 0.5 }} }}
"""
    path = directory / "schemathesis.toml"
    path.write_text(text)
    return path


def run_schemathesis(base_url: str, workdir: Path, ids: Ids, *, key: str | None,  # noqa: PLR0913
                     max_examples: int, seed: int = 1, timeout: float = 3600.0,
                     workers: int = 1, phases: str | None = None) -> FuzzRun:
    """Run the schemathesis CLI against ``base_url`` (with ``key`` as bearer token, if any)."""
    workdir.mkdir(parents=True, exist_ok=True)
    config = write_config(workdir, ids)
    har = workdir / "requests.har"
    exe = Path(sys.executable).parent / "schemathesis"
    cmd = [str(exe) if exe.is_file() else "schemathesis", "--config-file", str(config), "run",
           f"{base_url}/openapi.json", "--checks", "not_a_server_error",
           "--max-examples", str(max_examples), "--seed", str(seed), "--workers", str(workers),
           "--continue-on-failure", "--generation-database", "none", "--no-color",
           "--request-timeout", "30", "--report", "har", "--report-har-path", str(har),
           "--suppress-health-check", "all"]
    if key is not None:
        cmd += ["--header", f"Authorization: Bearer {key}"]
    if phases is not None:
        cmd += ["--phases", phases]
    start = time.monotonic()
    done = subprocess.run(cmd, cwd=workdir, capture_output=True, text=True, timeout=timeout,
                          check=False)
    seconds = time.monotonic() - start
    entries = json.loads(har.read_text())["log"]["entries"] if har.exists() else []
    statuses = collections.Counter(int(e["response"]["status"]) for e in entries)
    errors = [f"{e['request']['method']} {e['request']['url']} -> {e['response']['status']}"
              for e in entries if int(e["response"]["status"]) >= 500]
    return FuzzRun(len(entries), statuses, errors, done.returncode, seconds,
                   done.stdout + done.stderr)


def report(label: str, run: FuzzRun, tracebacks: int) -> str:
    """One paragraph of numbers."""
    by_class = collections.Counter(f"{s // 100}xx" for s in run.statuses.elements())
    lines = [f"{label}: {run.requests} requests in {run.seconds:.0f} s, exit code "
             f"{run.exit_code}, {len(run.server_errors)} answers 5xx, {tracebacks} tracebacks "
             "in the server log",
             "  by class: " + ", ".join(f"{k} {v}" for k, v in sorted(by_class.items())),
             "  by status: " + ", ".join(f"{k} {v}" for k, v in sorted(run.statuses.items()))]
    lines += [f"  5xx: {e}" for e in run.server_errors[:20]]
    return "\n".join(lines)


def main() -> int:
    """Fuzz a server with API keys, then one without; print the numbers."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from service_common import running_server, temp_dir

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--max-examples", type=int, default=400,
                        help="test cases per operation and phase (default 400)")
    parser.add_argument("--seeds", default="1,2",
                        help="comma-separated seeds: one run per seed and server (default 1,2)")
    args = parser.parse_args()
    failed = False
    total = 0
    for label, env, key in (("with an API key", {"BONEFIT_API_KEYS": json.dumps({KEY: "f"})},
                             KEY), ("without API keys (loopback)", {}, None)):
        with temp_dir("bonefit-fuzz-") as tmp, running_server(
                tmp / "data", no_worker=True, extra_env={
                    **env, "BONEFIT_MAX_UPLOAD_BYTES": str(1024 * 1024)}) as server:
            headers = {"Authorization": f"Bearer {key}"} if key else {}
            with httpx.Client(base_url=server.base_url, headers=headers, timeout=60) as client:
                ids = seed_ids(client)
            worker_elsewhere(tmp / "data")
            for seed in (int(s) for s in args.seeds.split(",")):
                run = run_schemathesis(server.base_url, tmp / f"st-{seed}", ids, key=key,
                                       max_examples=args.max_examples, seed=seed)
                log = server.log.read_text(errors="replace")
                tracebacks = log.count("Traceback")
                print(report(f"{label}, seed {seed}", run, tracebacks), flush=True)
                if not run.ok or tracebacks:
                    failed = True
                    print(run.output[-6000:])
                    print(log[-6000:])
                total += run.requests
    print(f"total: {total} requests")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
