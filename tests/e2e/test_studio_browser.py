"""The studio page in a real headless Chromium against a real `bonefit serve`: upload, live
progress, the 3D result and downloads; API keys and tenants; a bad file; the translation view;
the page's small JS modules; the offline API docs."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import httpx
import pytest

from tests.e2e.conftest import ServerProcess

if TYPE_CHECKING:
    from playwright.sync_api import Browser, Page

pytest_plugins = ["tests.e2e.services", "tests.e2e.browser"]
pytestmark = pytest.mark.slow
TIMEOUT_MS = 90_000
BAD_CSV = b"time,foo\n0,1\n"


def expect(locator: Any) -> Any:
    """Playwright's web-first assertions (they poll without eval, which the page's CSP
    forbids), with the tests' timeout."""
    from playwright.sync_api import expect as playwright_expect

    playwright_expect.set_options(timeout=TIMEOUT_MS)
    return playwright_expect(locator)


def open_page(browser: Browser, url: str, **context: Any) -> Page:
    """A fresh tab (its own sessionStorage) on ``url``; offline except for the server."""
    origin = "/".join(url.split("/")[:3])
    page = browser.new_context(viewport={"width": 1280, "height": 860}, **context).new_page()
    page.set_default_timeout(TIMEOUT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(origin)
               else route.abort())  # no CDN: anything off the server fails
    page.errors = errors  # type: ignore[attr-defined]
    page.goto(url)
    return page


def ready(page: Page) -> None:
    page.wait_for_selector("body[data-ready=true]", state="attached")
    assert page.errors == [], page.errors  # type: ignore[attr-defined]


def upload(page: Page, *files: Path) -> None:
    page.set_input_files("#file-input", [str(f) for f in files])


def upload_state(page: Page, name: str) -> tuple[str, str]:
    """Wait for the upload of ``name`` to end; its state (ok/error) and the text shown."""
    cell = page.wait_for_selector(f'#uploads tr[data-file="{name}"] td.info[data-state]')
    assert cell is not None
    return cell.get_attribute("data-state") or "", cell.inner_text()


def run_job(page: Page) -> str:
    """Start jobs for the ticked uploads; wait for the newest job to succeed; its id."""
    page.click("#submit-jobs")
    row = page.wait_for_selector("#jobs tbody tr[data-status=succeeded]:first-child")
    assert row is not None
    assert row.inner_text().count("100 %") == 1, row.inner_text()
    return row.get_attribute("data-job") or ""


def canvas_png(page: Page) -> str:
    data: str = page.evaluate("document.querySelector('#stage').toDataURL()")
    return data


def scrub(page: Page, frame: int) -> None:
    page.fill("#frame", str(frame))
    page.dispatch_event("#frame", "input")


def test_upload_watch_view_and_download(start_server: Callable[..., ServerProcess],
                                        browser: Browser, sensor_csv_bytes: bytes,
                                        tmp_path: Path) -> None:
    server = start_server()  # loopback only: no key is asked for
    take = tmp_path / "walk.csv"
    take.write_bytes(sensor_csv_bytes)
    page = open_page(browser, server.base_url)
    ready(page)
    assert page.is_hidden("#key-dialog")
    upload(page, take)
    state, text = upload_state(page, "walk.csv")
    assert state == "ok"
    assert text == "sensor-csv · 240 frames · 15 sensors · 60 fps · m", text
    job_id = run_job(page)
    page.click(f'#jobs tr[data-job="{job_id}"] a')
    page.wait_for_url(f"{server.base_url}/jobs/{job_id}")
    page.wait_for_selector("#stage")
    expect(page.locator("#joint-table tbody tr")).to_have_count(16)
    first = canvas_png(page)
    scrub(page, 120)
    assert page.input_value("#frame") == "120"
    assert canvas_png(page) != first  # the skeleton moved between the two playback times
    scrub(page, 0)
    assert canvas_png(page) == first
    with page.expect_download() as download:
        page.click("#downloads button[data-format=bvh]")
    assert download.value.suggested_filename == f"skeleton-{job_id}.bvh"
    assert Path(download.value.path()).read_text().startswith("HIERARCHY")
    with page.expect_download() as download:  # the binary result is offered too
        page.click("#downloads button[data-format=npz]")
    assert download.value.suggested_filename == f"skeleton-{job_id}.npz"
    assert Path(download.value.path()).read_bytes().startswith(b"PK")
    page.reload()  # the deep link works on its own
    page.wait_for_selector("#stage")
    assert page.errors == []  # type: ignore[attr-defined]


def test_api_key_bad_file_and_tenants(start_server: Callable[..., ServerProcess],
                                      browser: Browser, sensor_csv_bytes: bytes,
                                      tmp_path: Path) -> None:
    server = start_server({"BONEFIT_API_KEYS": json.dumps({"key-a": "studio-a",
                                                           "key-b": "studio-b"})})
    take, bad = tmp_path / "walk.csv", tmp_path / "broken.csv"
    take.write_bytes(sensor_csv_bytes)
    bad.write_bytes(BAD_CSV)
    page = open_page(browser, server.base_url)
    page.wait_for_selector("#key-dialog[open]")
    page.fill("#key-input", "not-a-key")
    page.press("#key-input", "Enter")
    page.wait_for_selector("#key-error:has-text('That key was refused.')")
    page.fill("#key-input", "key-a")
    page.press("#key-input", "Enter")
    ready(page)
    upload(page, take, bad)
    assert upload_state(page, "walk.csv")[0] == "ok"
    state, text = upload_state(page, "broken.csv")
    assert state == "error"
    assert "unknown column 'foo'" in text, text  # the problem's detail, next to the file
    assert "line 1" in text
    job_id = run_job(page)
    assert page.locator("#jobs tbody tr").count() == 1

    other = open_page(browser, server.base_url)  # another tab: asks again, another tenant
    other.wait_for_selector("#key-dialog[open]")
    other.fill("#key-input", "key-b")
    other.press("#key-input", "Enter")
    ready(other)
    other.wait_for_selector("#jobs-empty", state="visible")
    assert other.locator("#jobs tbody tr").count() == 0
    other.goto(f"{server.base_url}/jobs/{job_id}")  # the tab keeps its key across loads
    ready(other)
    assert other.is_hidden("#key-dialog")
    other.wait_for_selector(f"#result-error:has-text(\"no job '{job_id}'\")")
    assert other.locator("#stage").count() == 0


def test_jobs_cancel_retry_and_filter(start_server: Callable[..., ServerProcess],
                                     browser: Browser, long_sensor_csv_bytes: bytes,
                                     tmp_path: Path) -> None:
    # a running job notices a cancel at its next progress report (its lease's heartbeat
    # looks for one every half second), well inside the job
    server = start_server({"BONEFIT_WORKERS": "1"})
    take = tmp_path / "long.csv"
    take.write_bytes(long_sensor_csv_bytes)
    page = open_page(browser, server.base_url)
    ready(page)
    upload(page, take)
    assert upload_state(page, "long.csv")[0] == "ok"
    page.click("#submit-jobs")
    cancel = page.get_by_role("button", name="Cancel job of long.csv")
    cancel.focus()
    page.wait_for_selector("#jobs tbody tr[data-status=running]")
    expect(page.locator("#jobs tbody tr .pct")).not_to_have_text(" 0 %")  # progress events...
    assert page.evaluate("document.activeElement.getAttribute('aria-label')") == \
        "Cancel job of long.csv"  # ...and the focus stays on the button
    page.keyboard.press("Enter")  # the controls work from the keyboard
    page.wait_for_selector("#jobs tbody tr[data-status=cancelled]")
    page.get_by_role("button", name="Retry job of long.csv").click()
    expect(page.locator("#jobs tbody tr")).to_have_count(2)
    first, retried = (page.locator("#jobs tbody tr").nth(i).get_attribute("data-job")
                      for i in (1, 0))
    assert first != retried
    page.locator(f'#jobs tr[data-job="{retried}"] button').click()  # cancel the retry too
    expect(page.locator("#jobs tbody tr[data-status=cancelled]")).to_have_count(2)
    page.select_option("#status-filter", "succeeded")
    page.wait_for_selector("#jobs-empty", state="visible")
    assert page.locator("#jobs tbody tr").count() == 0
    page.select_option("#status-filter", "cancelled")
    expect(page.locator("#jobs tbody tr")).to_have_count(2)


def test_translation_view(start_server: Callable[..., ServerProcess], browser: Browser,
                          kinematics_csv_bytes: bytes, tmp_path: Path) -> None:
    server = start_server()
    take = tmp_path / "walker.csv"
    take.write_bytes(kinematics_csv_bytes)
    page = open_page(browser, server.base_url)
    ready(page)
    upload(page, take)
    state, text = upload_state(page, "walker.csv")
    assert state == "ok"
    assert text.startswith("kinematics-csv"), text
    assert page.input_value("#kind") == "translation"  # chosen from the sniffed format
    assert page.is_visible("#param-left_foot")
    job_id = run_job(page)
    page.goto(f"{server.base_url}/jobs/{job_id}")
    path = page.wait_for_selector("svg[aria-label='Root path seen from above'] polyline",
                                  state="attached")
    assert path is not None
    frames = len(kinematics_csv_bytes.decode().strip().splitlines()) - 1
    assert len((path.get_attribute("points") or "").split()) == frames
    assert page.locator("svg[aria-label='Contact phases'] rect").count() > 4
    heights = page.locator("svg[aria-label='Heights over time (m)']")
    assert heights.locator("polyline").count() == 4  # hips, floor, both feet (foot_heights)
    assert (heights.text_content() or "").count("Foot") == 2


def test_js_modules(start_server: Callable[..., ServerProcess], browser: Browser) -> None:
    server = start_server(worker=False)
    page = open_page(browser, server.base_url)
    ready(page)
    got = page.evaluate("""async () => {
      const schema = await import('/static/js/schema.js');
      const charts = await import('/static/js/charts.js');
      const sk = await import('/static/js/skeleton3d.js');
      const api = await import('/static/js/api.js');
      const openapi = await (await fetch('/openapi.json')).json();
      const kinds = schema.kindsOf(openapi);
      const fields = schema.fieldsOf(openapi, kinds.find((k) => k.kind === 'skeleton').params);
      const field = (n) => fields.find((f) => f.name === n);
      const upright = sk.uprighter([0, 0, 1])([0, 0, 1]).map((v) => Math.round(v * 1e9) / 1e9);
      const camera = {yaw: 0.3, pitch: 0.2, zoom: 1, center: [1, 2, 3], radius: 1};
      return {
        kinds: kinds.map((k) => k.kind).sort(),
        widgets: ['method', 'fps', 'up', 'stations', 'offsets', 'smooth', 'anthropometry',
                  'formats'].map((n) => field(n).widget),
        formats: schema.parseField(field('formats'), 'json, bvh').value,
        formatsBad: schema.parseField(field('formats'), 'json xml').error,
        fps0: schema.parseField(field('fps'), '0').error,
        fps: schema.parseField(field('fps'), '120').value,
        fpsEmpty: schema.parseField(field('fps'), '').value === undefined,
        w_s: schema.parseField(field('w_s'), '-1').error,
        i0: schema.parseField(field('i0'), '1.5').error,
        method: schema.parseField(field('method'), 'nope').error,
        up: schema.parseField(field('up'), '0, 0, 1').value,
        upBad: schema.parseField(field('up'), '0 1').error,
        stations: schema.parseField(field('stations'), '{"1": "pelvis"}').value,
        stationsBad: schema.parseField(field('stations'), '{"1": 2}').error,
        centre: sk.project([1, 2, 3], camera, 800, 600).slice(0, 2),
        upright,
        runs: charts.runs(['left', 'left', 'both', 'none', 'none']),
        events: api.parseEvents(
          'id: 4\\nevent: progress\\ndata: {"a": 1}\\n\\n: ka\\n\\nevent: end'),
        kind: schema.kindForFormat('tracker') + ' ' + schema.kindForFormat('bvh'),
      };
    }""")
    assert got["kinds"] == ["skeleton", "translation"]
    assert got["widgets"] == ["select", "number", "vector", "json", "calibration", "select",
                              "json-or-enum", "list"]
    assert got["formats"] == ["json", "bvh"]
    assert got["formatsBad"] == "xml: expected some of json, bvh, csv, npz"
    fps = next(a for a in httpx.get(f"{server.base_url}/openapi.json").json()["components"][
        "schemas"]["SkeletonParams"]["properties"]["fps"]["anyOf"] if a.get("type") == "number")
    if "exclusiveMinimum" in fps:  # the page checks what the schema says, whatever it says
        assert got["fps0"] == f"expected > {fps['exclusiveMinimum']:g}"
    else:
        assert got["fps0"] == f"expected ≥ {fps['minimum']:g}"
    assert got["fps"] == 120
    assert got["fpsEmpty"] is True
    assert got["w_s"] == "expected ≥ 0"
    assert got["i0"] == "expected a whole number"
    assert got["method"].startswith("expected one of auto, llsf")
    assert got["up"] == [0, 0, 1]
    assert got["upBad"] == "expected 3 numbers, e.g. 0, 1, 0"
    assert got["stations"] == {"1": "pelvis"}
    assert got["stationsBad"] == "1: expected string, got integer"
    assert got["centre"] == [400, 300]
    assert got["upright"] == [0, 1, 0]
    assert got["runs"] == [{"label": "left", "start": 0, "end": 2},
                           {"label": "both", "start": 2, "end": 3},
                           {"label": "none", "start": 3, "end": 5}]
    assert got["events"] == [[{"event": "progress", "data": '{"a": 1}', "id": "4"}],
                             "event: end"]
    assert got["kind"] == "skeleton translation"


def test_offline_api_docs(start_server: Callable[..., ServerProcess], browser: Browser) -> None:
    server = start_server(worker=False)
    page = open_page(browser, f"{server.base_url}/docs")
    page.wait_for_selector(".swagger-ui .info .title:has-text('bonefit')")
    page.wait_for_selector(".opblock-summary-path:has-text('/v1/jobs/{job_id}/events')")
    assert page.errors == []  # type: ignore[attr-defined]
    redoc = open_page(browser, f"{server.base_url}/redoc")
    redoc.wait_for_selector("h1:has-text('bonefit')")
    redoc.wait_for_selector("text=Follow a job (Server-Sent Events)")
