"""The web dashboard in a real browser (Debian's Chromium, headless, driven by Playwright) against a real
`nbake serve`: the token gate, submitting a quick render from the form and watching it finish, its preview,
a trained model's report and comparison, cancelling a running job (refused with a read token, done with a
submit token), job data shown as text (a scene named `<script>...` runs nothing), the list's duration, age
and filters kept in the address, two jobs compared (metric deltas; frames with a difference, zoom and
exposure), a failed job's one-line cause with its traceback collapsed, and pages that fit 420 px. Each page
is saved as a screenshot under `out/screenshots/` (or `$NBAKE_SCREENSHOTS`) for review."""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser, Page, expect, sync_playwright

from tests.integration import test_grpc_server as grpc_server
from tests.integration.test_api_server import TOKENS
from tests.integration.test_grpc_server import LONG, TINY
from workers.scene.generators.builtin import get_builtin

served = grpc_server.served  # fixture: one real `nbake serve` on free ports, stopped after the last user

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
SCREENSHOTS = Path(os.environ.get("NBAKE_SCREENSHOTS", "out/screenshots"))
JOB_TIMEOUT_MS = 180_000
# A trained job of a few seconds: the quick lsnif preset cut to 10 steps and 1024 held-out rays, the
# report's reference at 16 spp (what is checked is the report's display, not the model's quality).
SMALL_LSNIF = {
    "samplers": 0,
    "train": {"steps": 10, "checkpoint_every": 10, "progress_every": 5},
    "evaluation_rays": 1024,
    "reference_spp": 16,
}
HOSTILE_NAME = '<script>window.__injected = 1</script><img src=x onerror="window.__injected = 2">'
NARROW = {"width": 420, "height": 800}  # a phone
PAGE_WIDTHS = "[document.scrollingElement.scrollWidth, document.scrollingElement.clientWidth]"


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: `make test-packages` installs Debian's chromium")
    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_FLAGS)
        yield launched
        launched.close()


@pytest.fixture
def page(browser, served) -> Iterator[Page]:
    """A fresh tab (its own session storage) at the dashboard; any script error fails the test."""
    context = browser.new_context(viewport={"width": 1280, "height": 900}, base_url=served.url)
    opened = context.new_page()
    errors: list[str] = []
    opened.on("pageerror", lambda error: errors.append(str(error)))
    opened.goto("/ui")
    yield opened
    context.close()
    assert errors == [], errors


@pytest.fixture(scope="module", autouse=True)
def trained_job(served) -> str:
    """A small lsnif job, submitted as the module starts so that it trains while the first tests run."""
    body = {"kind": "lsnif", "scene": "thin_walls", "preset": "quick", "config": SMALL_LSNIF}
    return post_job(served, body)["id"]


@pytest.fixture(scope="module", autouse=True)
def other_trained_job(served) -> str:
    """The same job with another seed: its frame and figures differ from `trained_job`'s."""
    body = {"kind": "lsnif", "scene": "thin_walls", "preset": "quick", "config": SMALL_LSNIF, "seed": 1}
    return post_job(served, body)["id"]


def finished(served, job_id: str) -> dict:
    """The job once it is in a final state, polled over the API."""
    headers = {"Authorization": f"Bearer {TOKENS['read']}"}
    for _ in range(JOB_TIMEOUT_MS // 500):
        job = httpx.get(f"{served.url}/v1/jobs/{job_id}", headers=headers, timeout=60).json()
        if job["state"] in ("SUCCEEDED", "FAILED", "CANCELLED"):
            return job
        time.sleep(0.5)
    raise AssertionError(f"{job_id} did not finish: {job}")


def post_job(served, body: dict) -> dict:
    headers = {"Authorization": f"Bearer {TOKENS['submit']}"}
    response = httpx.post(f"{served.url}/v1/jobs", json=body, headers=headers, timeout=60)
    assert response.status_code in (200, 201), response.text
    return response.json()


def screenshot(page: Page, name: str) -> None:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=SCREENSHOTS / f"{name}.png", full_page=True)


def sign_in(page: Page, scope: str) -> None:
    page.fill("#token", TOKENS[scope])
    page.click("#login-form button[type=submit]")
    expect(page.locator("#sign-out")).to_be_visible()


def submit_from_form(page: Page, kind: str, scene: str, config: dict, shot: str | None = None) -> str:
    page.goto("/ui/#/submit")
    page.select_option("#kind", kind)
    page.select_option("#scene", scene)
    page.select_option("#preset", "quick")
    expect(page.locator("#preset-config")).to_contain_text('"samplers":')  # the preset's resolved config
    page.fill("#config", json.dumps(config))
    if shot:
        page.click("#submit-form details summary")
        screenshot(page, shot)
    page.click("#submit")
    page.wait_for_url(re.compile(r"#/jobs/job-"))
    return page.url.rsplit("/", 1)[-1]


def wait_for_state(page: Page, state: str) -> None:
    expect(page.locator(".job-header .state")).to_have_text(state, timeout=JOB_TIMEOUT_MS)


def test_no_token_no_data_and_the_token_is_asked_once_per_tab(page, browser, served):
    expect(page.locator("#login-form")).to_be_visible()
    assert page.locator("#jobs-table").count() == 0
    screenshot(page, "sign-in")
    page.fill("#token", "not-a-token")
    page.click("#login-form button[type=submit]")
    expect(page.locator(".problem")).to_contain_text("unknown token")
    sign_in(page, "read")
    expect(page.locator("#jobs-table")).to_be_visible()
    page.reload()  # the same tab keeps its token
    expect(page.locator("#jobs-table")).to_be_visible()
    page.click("#sign-out")
    expect(page.locator("#login-form")).to_be_visible()
    assert page.evaluate("sessionStorage.length") == 0

    response = httpx.get(f"{served.url}/ui/app.js")
    assert "script-src 'self'" in response.headers["content-security-policy"]
    assert httpx.get(f"{served.url}/ui").status_code in (307, 308)


def test_a_quick_render_submitted_from_the_form_finishes_live_with_its_preview(page):
    sign_in(page, "submit")
    screenshot(page, "jobs")
    page.goto("/ui/#/submit")
    page.select_option("#kind", "render")
    for bad, where in (("{spp: 8", "config: not valid JSON"), ('{"spp": 0}', "config.spp")):
        page.fill("#config", bad)
        page.click("#submit")  # refused: the field at fault is named and marked
        expect(page.locator("#submit-form .problem")).to_contain_text(where)
        expect(page.locator("#config")).to_have_attribute("aria-invalid", "true")
    job_id = submit_from_form(page, "render", "cornell_box", {"spp": 8, "samplers": 0}, "submit")
    wait_for_state(page, "SUCCEEDED")  # no reload
    expect(page.locator(".job-header .progress")).to_have_attribute("data-fraction", "1.000")
    expect(page.locator("#events .event-progress").first).to_be_visible()  # read from the SSE stream
    expect(page.locator("#events")).to_contain_text("RUNNING → SUCCEEDED")
    expect(page.locator("#plan")).to_contain_text("estimated")
    expect(page.locator("#log")).not_to_be_empty()
    screenshot(page, "job")

    page.click("[data-tab=files]")
    preview = page.locator('img[data-file="preview.png"]')
    expect(preview).to_be_visible()
    assert preview.evaluate("img => img.complete && img.naturalWidth") == 64
    expect(page.locator("#files")).to_contain_text("image.exr")
    screenshot(page, "files")
    page.click("[data-tab=report]")
    expect(page.locator("#tab-report")).to_contain_text("trains no model")

    page.goto("/ui/#/jobs")
    row = page.locator(f'tr[data-job="{job_id}"]')
    expect(row.locator(".state")).to_have_text("SUCCEEDED")


def test_a_trained_job_shows_its_speed_error_report_and_comparison(page, trained_job):
    sign_in(page, "admin")
    page.goto(f"/ui/#/jobs/{trained_job}")
    wait_for_state(page, "SUCCEEDED")

    page.goto(f"/ui/#/jobs/{trained_job}/report")
    plots = page.locator("#speed-error svg")
    expect(plots).to_have_count(2)
    table = page.locator("#report-table tbody tr")
    path_traced = table.filter(has_text="path tracing").count()
    assert path_traced >= 2  # 1 and 4 spp below the 16-spp reference
    for plot in plots.all():
        expect(plot.locator(".traced[data-point]")).to_have_count(path_traced)
        expect(plot.locator(".equal[data-point]")).to_have_count(1)
        expect(plot.locator(".model[data-point]")).to_have_count(1)
    expect(page.locator("#report-table .model-row")).to_contain_text("lsnif")
    expect(page.locator("#equal-time-ratio")).to_contain_text("x path tracing's time by FLIP")
    screenshot(page, "report")

    page.click("[data-tab=compare]")
    frame = page.locator("#compare-frame")
    expect(frame).to_be_visible()
    sizes = page.evaluate(
        "['compare-reference', 'compare-frame'].map(id => document.getElementById(id).naturalWidth)"
    )
    assert sizes[0] == sizes[1] > 0
    page.locator("#compare-slider").fill("25")
    assert frame.evaluate("img => img.style.clipPath") == "inset(0px 0px 0px 25%)"
    box = page.locator("#compare").bounding_box()
    page.mouse.move(box["x"] + 0.5 * box["width"], box["y"] + 10)
    page.mouse.down()
    page.mouse.move(box["x"] + 0.75 * box["width"], box["y"] + 10)
    page.mouse.up()
    assert abs(float(page.locator("#compare-slider").input_value()) - 75) < 1
    expect(page.locator("#side-by-side canvas")).to_have_count(3)  # reference, frame, difference
    screenshot(page, "compare")


def test_a_job_named_script_is_shown_as_text_and_cancelled_with_a_submit_token(page, served):
    scene = get_builtin("cornell_box").model_dump(mode="json") | {"name": HOSTILE_NAME}
    config = LONG | {"samplers": 0}  # rendered in the driver: no sampler actors to start
    body = {"kind": "render", "scene": scene, "preset": "quick", "config": config, "force": True}
    job = post_job(served, body)

    with page.expect_request(lambda request: f"/v1/jobs/{job['id']}/events" in request.url):
        sign_in(page, "read")  # the list follows the unfinished job's event stream
    row = page.locator(f'tr[data-job="{job["id"]}"]')
    expect(row.locator(".scene")).to_have_text(f"{HOSTILE_NAME} (inline)")
    # Its progress moves without a reload.
    progress = row.locator(".progress")
    expect(progress).not_to_have_attribute("data-fraction", "0.000", timeout=JOB_TIMEOUT_MS)
    seen = progress.get_attribute("data-fraction")
    expect(progress).not_to_have_attribute("data-fraction", seen, timeout=JOB_TIMEOUT_MS)
    assert float(progress.get_attribute("data-fraction")) > float(seen)
    screenshot(page, "jobs-running")
    page.goto(f"/ui/#/jobs/{job['id']}")
    expect(page.locator(".job-header .scene")).to_have_text(f"{HOSTILE_NAME} (inline)")
    assert page.evaluate("window.__injected") is None
    assert page.locator("#view script, #view img[src=x]").count() == 0

    wait_for_state(page, "RUNNING")
    page.click("#cancel")  # a read token may not cancel
    expect(page.locator(".cancel-status .problem")).to_contain_text("403")
    page.click("#sign-out")
    sign_in(page, "submit")
    page.goto(f"/ui/#/jobs/{job['id']}")
    wait_for_state(page, "RUNNING")
    page.click("#cancel")
    wait_for_state(page, "CANCELLED")
    screenshot(page, "cancelled")
    assert page.evaluate("window.__injected") is None


def test_the_job_list_has_duration_age_and_filters_kept_in_the_url(page, served, trained_job):
    assert finished(served, trained_job)["state"] == "SUCCEEDED"
    sign_in(page, "read")
    page.goto("/ui/#/jobs?kind=lsnif")
    row = page.locator(f'tr[data-job="{trained_job}"]')
    expect(row).to_be_visible()
    expect(page.locator("#kind-filter")).to_have_value("lsnif")
    kinds = page.locator("#jobs-table tbody td.kind").all_inner_texts()
    assert kinds and set(kinds) == {"lsnif"}, kinds
    expect(row.locator(".duration")).to_have_text(re.compile(r"\d+(\.\d)? (ms|s|min)"))
    expect(row.locator(".age")).to_have_text(re.compile(r"\d+ (s|min|h|d) ago"))

    page.select_option("#state-filter", "FAILED")
    page.wait_for_url(re.compile(r"state=FAILED"))
    assert "kind=lsnif" in page.url
    expect(row).to_have_count(0)
    page.reload()  # the filtered view is a link
    expect(page.locator("#state-filter")).to_have_value("FAILED")
    expect(page.locator("#kind-filter")).to_have_value("lsnif")
    page.select_option("#state-filter", "SUCCEEDED")
    expect(row).to_be_visible()
    screenshot(page, "jobs-filtered")


# The summed red, green and blue of every pixel of a canvas of the frame viewer.
CANVAS_SUM = """canvas => {
  const data = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
  let sum = 0;
  for (let i = 0; i < data.length; i += 4) sum += data[i] + data[i + 1] + data[i + 2];
  return sum;
}"""


def test_two_jobs_compared_with_metric_deltas_difference_zoom_and_exposure(
    page, served, trained_job, other_trained_job
):
    for job_id in (trained_job, other_trained_job):
        assert finished(served, job_id)["state"] == "SUCCEEDED"
    sign_in(page, "read")
    page.goto("/ui/#/jobs?kind=lsnif")
    compare = page.locator("#compare-selected")
    page.locator(f'tr[data-job="{trained_job}"] input.pick').check()
    expect(compare).to_be_disabled()
    page.locator(f'tr[data-job="{other_trained_job}"] input.pick').check()
    compare.click()
    page.wait_for_url(re.compile(r"#/compare/job-.+/job-"))

    flip = page.locator('#compare-metrics tr[data-metric="flip"]')
    expect(flip.locator(".delta")).to_have_text(re.compile(r"^[+−]\d"))  # the seeds' models differ
    difference = page.locator('canvas[data-panel="frame difference"]')
    expect(difference).to_be_visible()
    assert difference.evaluate(CANVAS_SUM) > 0
    frame = page.locator('canvas[data-panel="A frame"]')
    natural = frame.evaluate("canvas => canvas.width")
    page.select_option("#zoom", "16")  # wider than the view: it scrolls
    assert frame.evaluate("canvas => canvas.getBoundingClientRect().width") == 16 * natural
    views = page.locator(".viewport")
    assert views.first.evaluate("view => { view.scrollLeft = 37; return view.scrollLeft; }") == 37
    expect(views.nth(1)).to_have_js_property("scrollLeft", 37)  # synchronized
    dark = frame.evaluate(CANVAS_SUM)
    page.locator("#exposure").fill("1")
    page.locator("#exposure").dispatch_event("input")
    assert frame.evaluate(CANVAS_SUM) > dark
    screenshot(page, "compare-jobs")

    page.goto(f"/ui/#/compare/{trained_job}/{trained_job}")
    expect(page.locator('canvas[data-panel="frame difference"]')).to_be_visible()
    assert page.locator('canvas[data-panel="frame difference"]').evaluate(CANVAS_SUM) == 0
    expect(page.locator('#compare-metrics tr[data-metric="flip"] .delta')).to_have_text("0")

    page.goto(f"/ui/#/jobs/{trained_job}")
    page.click("#compare-with")  # from a job page: the list with this job picked
    expect(page.locator(f'tr[data-job="{trained_job}"] input.pick')).to_be_checked()

    page.goto(f"/ui/#/jobs/{trained_job}/compare")  # within one job: the same viewer
    within = page.locator('canvas[data-panel="difference"]')
    expect(within).to_be_visible()
    assert within.evaluate(CANVAS_SUM) > 0
    expect(page.locator("#zoom")).to_be_visible()
    expect(page.locator("#exposure")).to_be_visible()


def dark_scene() -> dict:
    """Valid at submission, but it has no light, so the render fails when it runs."""
    spec = get_builtin("cornell_box").model_dump(mode="json", exclude_none=True)
    spec["objects"] = [o for o in spec["objects"] if not o.get("emission")]
    return spec


def test_a_failed_job_shows_its_cause_in_one_line_and_its_traceback_collapsed(page, served):
    body = {"kind": "render", "scene": dark_scene(), "preset": "quick", "config": TINY | {"samplers": 0}}
    job = post_job(served, body | {"force": True})
    assert finished(served, job["id"])["state"] == "FAILED"
    sign_in(page, "read")
    page.goto(f"/ui/#/jobs/{job['id']}")
    traceback = page.locator(".failure details.traceback")
    expect(traceback.locator("summary")).to_be_visible()
    expect(traceback).not_to_have_attribute("open", "")
    cause = page.locator(".failure .cause")
    expect(cause).to_contain_text("light")
    line = cause.evaluate("element => parseFloat(getComputedStyle(element).fontSize)")
    expect(traceback.locator("pre")).to_contain_text("Traceback", use_inner_text=False)
    logged = page.locator("#events tr.event-log", has_text="Traceback")
    expect(logged.locator("details.traceback")).to_have_count(1)
    assert logged.bounding_box()["height"] < 3 * line  # collapsed, not flattened into the table
    screenshot(page, "failed")
    page.set_viewport_size(NARROW)  # narrower than the cause: still one line
    assert cause.bounding_box()["height"] < 2 * line


def test_narrow_pages_do_not_overflow(browser, served, trained_job, other_trained_job):
    for job_id in (trained_job, other_trained_job):
        assert finished(served, job_id)["state"] == "SUCCEEDED"
    context = browser.new_context(viewport=NARROW, base_url=served.url)
    narrow = context.new_page()
    narrow.goto("/ui")
    sign_in(narrow, "read")
    pages = {
        "jobs": ("#/jobs", "#jobs-table tbody tr"),
        "job": (f"#/jobs/{trained_job}", "#events tbody tr"),
        "report": (f"#/jobs/{trained_job}/report", "#report-table"),
        "compare": (f"#/jobs/{trained_job}/compare", "#compare"),
        "compare-jobs": (f"#/compare/{trained_job}/{other_trained_job}", "#compare-metrics"),
    }
    for name, (where, shown) in pages.items():
        narrow.goto(f"/ui/{where}")
        expect(narrow.locator(shown).first).to_be_visible()
        widths = narrow.evaluate(PAGE_WIDTHS)
        assert widths[0] <= widths[1], (name, widths)
        screenshot(narrow, f"narrow-{name}")
    context.close()
