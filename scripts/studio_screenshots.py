"""Screenshots of the studio's views for docs/studio.md, taken in headless Chromium.

    .venv/bin/python scripts/studio_screenshots.py [--out docs/images] [--chromium PATH]

Starts its own `bonefit serve` (loopback only, temporary data directory) on a free port,
generates a sensor take, an inertial-suit take and a broken file, and drives the page like the
browser tests do (tests/e2e/test_studio_browser.py). Needs Debian's chromium and Playwright
for Python (the `dev` extra); takes about 30 s.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextlib.contextmanager
def server(data: Path) -> Iterator[str]:
    """`bonefit serve` on a free loopback port until the block exits; its base URL."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("BONEFIT_")}
    bonefit = Path(sys.executable).with_name("bonefit")
    proc = subprocess.Popen([str(bonefit), "serve", "--port", str(port), "--data-dir", str(data)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(300):
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                    break
            time.sleep(0.2)
        yield url
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(30)


def make_takes(folder: Path) -> tuple[Path, Path, Path]:
    """A 15-sensor take (CSV, cm), an inertial-suit take (kinematics CSV) and a broken file."""
    from bonefit.estimation.io.kinematics import write_kinematics_csv
    from bonefit.estimation.io.sensors import write_sensor_csv
    from bonefit.estimation.simulate.inertial import simulate_walker
    from bonefit.estimation.simulate.sensors import example_motion, simulate_sensors

    recording, _ = simulate_sensors(example_motion(n_frames=360, fps=60.0, seed=3),
                                    units_m=0.01, seed=3)
    sensors = folder / "walk_take03.csv"
    write_sensor_csv(recording, sensors)
    rec, _, _ = simulate_walker(fps=60.0, seed=0)
    suit = folder / "suit_walk.csv"
    write_kinematics_csv(rec, suit)
    broken = folder / "broken_take.csv"
    broken.write_text("time,pelvis.x,pelvis.y,pelvis.z,pelvis.qw,foo\n0,0,0,0,1,0\n")
    return sensors, suit, broken


def shoot(url: str, takes: tuple[Path, Path, Path], out: Path, chromium: str) -> list[Path]:
    from playwright.sync_api import expect, sync_playwright

    sensors, suit, broken = takes
    shots: list[Path] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=ARGS)
        page = browser.new_page(viewport={"width": 1200, "height": 760})
        page.set_default_timeout(90_000)
        page.goto(url)
        page.wait_for_selector("body[data-ready=true]", state="attached")
        page.set_input_files("#file-input", [str(sensors), str(broken)])
        for name in (sensors.name, broken.name):
            page.wait_for_selector(f'#uploads tr[data-file="{name}"] td.info[data-state]')
        page.fill("#param-fps", "0")
        page.click("#submit-jobs")  # shows the schema's validation next to the field
        page.fill("#param-fps", "")
        page.evaluate("window.scrollTo(0, 0)")
        shots.append(out / "studio-upload.png")
        page.screenshot(path=shots[-1])
        page.click("#submit-jobs")
        page.wait_for_selector("#jobs tbody tr[data-status=succeeded]")
        page.set_input_files("#file-input", [str(suit)])
        page.wait_for_selector(f'#uploads tr[data-file="{suit.name}"] td.info[data-state]')
        page.click("#submit-jobs")
        expect(page.locator("#jobs tbody tr[data-status=succeeded]")).to_have_count(2,
                                                                              timeout=90_000)
        shots.append(out / "studio-jobs.png")
        page.locator("#jobs-title").scroll_into_view_if_needed()
        page.screenshot(path=shots[-1])
        rows = page.locator("#jobs tbody tr")
        translation, skeleton = (rows.nth(i).get_attribute("data-job") for i in (0, 1))
        page.goto(f"{url}/jobs/{skeleton}")
        page.wait_for_selector("#stage")
        page.check("#trails")
        page.fill("#frame", "150")
        page.dispatch_event("#frame", "input")
        page.evaluate("window.scrollTo(0, 0)")
        shots.append(out / "studio-skeleton.png")
        page.screenshot(path=shots[-1])
        page.goto(f"{url}/jobs/{translation}")
        page.wait_for_selector("svg[aria-label='Heights over time (m)']")
        shots.append(out / "studio-translation.png")
        page.screenshot(path=shots[-1])
        page.goto(f"{url}/docs")
        page.wait_for_selector(".swagger-ui .info .title")
        shots.append(out / "studio-api-docs.png")
        page.screenshot(path=shots[-1])
        browser.close()
    return shots


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    parser.add_argument("--chromium", default="/usr/bin/chromium")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp, server(Path(tmp) / "data") as url:
        takes = make_takes(Path(tmp))
        for shot in shoot(url, takes, args.out, args.chromium):
            print(f"{shot.relative_to(ROOT) if shot.is_relative_to(ROOT) else shot}: "
                  f"{shot.stat().st_size // 1024} KiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
