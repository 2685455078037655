"""The web page in a real headless Chromium (selenium + Debian ``chromium-driver``): open ``/``,
submit the paper's task through the form, land on the plan page and see its figures loaded;
submit a small tuning job and watch its page reach ``succeeded`` with the convergence figure;
the API docs (Swagger UI at ``/docs``, ReDoc at ``/redoc``) render every operation offline.

The browser resolves no host name but 127.0.0.1 (``--host-resolver-rules``): every page works
without the network.

Chromium and chromedriver are installed by ``tests/browser/setup.sh`` when missing (apt-get,
needs root or sudo). Set ``SPACEARM_SKIP_BROWSER_TESTS=1`` to skip these tests on a machine
where that is impossible. Screenshots go to ``$SPACEARM_SCREENSHOTS`` (default
``/tmp/spacearm-screens``)."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.service.conftest import PAPER_TASK, ROOT, Stack

SETUP = ROOT / "tests" / "browser" / "setup.sh"
SCREENS = Path(os.environ.get("SPACEARM_SCREENSHOTS", "/tmp/spacearm-screens"))
CHROMIUM_FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--window-size=1400,1000",
    "--enable-unsafe-swiftshader",  # WebGL in software (the 3D view), without a GPU
    # offline: no name resolves but the test stack's address
    "--host-resolver-rules=MAP * ~NOTFOUND , EXCLUDE 127.0.0.1",
]

COMPARE_SRC = "const i = document.querySelector('#compare-image'); return i ? i.src : ''"
ALL_IMAGES_LOADED = """
const imgs = Array.from(document.querySelectorAll(arguments[0]));
return imgs.length > 0 && imgs.every(i => i.complete && i.naturalWidth > 0);
"""


def _binaries() -> tuple[str | None, str | None]:
    return shutil.which("chromium") or shutil.which("chromium-browser"), shutil.which("chromedriver")


@pytest.fixture(scope="module")
def browser_binaries() -> tuple[str, str]:
    if os.environ.get("SPACEARM_SKIP_BROWSER_TESTS") == "1":
        pytest.skip("SPACEARM_SKIP_BROWSER_TESTS=1")
    chromium, driver = _binaries()
    if not (chromium and driver):
        done = subprocess.run(["sh", str(SETUP)], capture_output=True, text=True, timeout=900)
        chromium, driver = _binaries()
        if not (chromium and driver):
            pytest.fail(f"tests/browser/setup.sh could not install chromium + chromedriver:\n{done.stdout}\n{done.stderr}")
    assert chromium and driver
    return chromium, driver


@pytest.fixture(scope="module")
def driver(browser_binaries: tuple[str, str]) -> Iterator[Any]:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium, chromedriver = browser_binaries
    profile = tempfile.mkdtemp(prefix="spacearm-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for flag in [*CHROMIUM_FLAGS, f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # console messages, CSP reports among them
    drv = webdriver.Chrome(options=options, service=Service(executable_path=chromedriver))
    drv.set_page_load_timeout(120)
    SCREENS.mkdir(parents=True, exist_ok=True)
    try:
        yield drv
    finally:
        drv.quit()
        shutil.rmtree(profile, ignore_errors=True)


def screenshot(drv: Any, name: str) -> Path:
    """A full-page screenshot (the window grows to the page height first)."""
    height = int(drv.execute_script("return Math.max(document.body.scrollHeight, document.documentElement.scrollHeight)"))
    drv.set_window_size(1400, min(max(height + 40, 800), 6000))
    path = SCREENS / f"{name}.png"
    assert drv.save_screenshot(str(path))
    drv.set_window_size(1400, 1000)
    return path


def wait_until(drv: Any, condition: Any, timeout: float = 60.0) -> Any:
    from selenium.webdriver.support.ui import WebDriverWait

    return WebDriverWait(drv, timeout, poll_frequency=0.1).until(condition)


def test_submit_paper_task_and_see_plan_figures(driver: Any, stack: Stack) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver.get(stack.url + "/")
    assert "spacearm" in driver.title
    assert "table1" in driver.find_element(By.ID, "robots").text
    Select(driver.find_element(By.ID, "preset")).select_by_value("paper-line")
    Select(driver.find_element(By.ID, "method")).select_by_value("adaptive")
    for name, value in (("adaptive.lambda_max", "0.06"), ("adaptive.epsilon", "0.12")):
        field = driver.find_element(By.NAME, name)
        assert field.is_displayed()
        field.clear()
        field.send_keys(value)
    assert not driver.find_element(By.NAME, "dls.lambda").is_displayed()  # only the chosen method's parameters
    screenshot(driver, "01-index-form")
    driver.find_element(By.ID, "plan-submit").click()

    wait_until(driver, lambda d: "/plans/" in d.current_url)
    plan_id = driver.current_url.rstrip("/").rsplit("/", 1)[-1]
    assert driver.find_element(By.ID, "plan-status").text == "success"
    summary = driver.find_element(By.ID, "summary").text
    assert "adaptive" in summary and "epsilon=0.12" in summary
    metrics = driver.find_element(By.ID, "metrics").text
    assert "max position error [mm]" in metrics and "max joint speed [deg/s]" in metrics
    images = driver.find_elements(By.CSS_SELECTOR, "#figures img")
    assert [i.get_attribute("data-figure") for i in images] == [
        "ee-velocity",
        "gjm-determinant",
        "joint-velocities",
        "joint-angles",
        "tracking-errors",
        "base-motion",
        "damping",
        "joint-torques",
        "carrier-wrench",
        "clearance",
        "robustness",
        "scene-3d",
    ]
    wait_until(driver, lambda d: d.execute_script(ALL_IMAGES_LOADED, "#figures img"))
    widths = driver.execute_script("return Array.from(document.querySelectorAll('#figures img')).map(i => i.naturalWidth)")
    assert all(w > 0 for w in widths)
    screenshot(driver, "02-plan-page")

    with stack.client() as c:
        stored = c.get(f"/v1/plans/{plan_id}").json()
    assert stored["method"] == {"name": "adaptive", "params": {"lambda_max": 0.06, "epsilon": 0.12}}

    # a bad parameter comes back next to its field, in the form's words, once
    driver.get(stack.url + "/")
    Select(driver.find_element(By.ID, "method")).select_by_value("dls")
    field = driver.find_element(By.NAME, "dls.lambda")
    field.clear()
    field.send_keys("-1")
    driver.find_element(By.ID, "plan-submit").click()
    wait_until(driver, lambda d: d.find_elements(By.CSS_SELECTOR, ".field-error"))
    (error,) = driver.find_elements(By.CSS_SELECTOR, ".field-error")
    assert error.get_attribute("data-field") == "dls.lambda" and error.text == "must be greater than or equal to 0"
    assert error.is_displayed() and error.find_element(By.XPATH, "..").find_element(By.NAME, "dls.lambda")  # beside it
    assert not driver.find_elements(By.ID, "form-error") and "body." not in driver.find_element(By.TAG_NAME, "body").text
    assert Select(driver.find_element(By.ID, "method")).first_selected_option.get_attribute("value") == "dls"
    assert driver.find_element(By.NAME, "dls.lambda").get_attribute("value") == "-1"  # the form keeps what was typed
    screenshot(driver, "03-form-error")


def test_submit_tuning_job_and_follow_progress(driver: Any, stack: Stack) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver.get(stack.url + "/")
    form = driver.find_element(By.ID, "job-form")
    # a job of several seconds (the raster scan, a large population), so the page follows it live
    Select(form.find_element(By.NAME, "preset")).select_by_value("raster-patch")
    for name, value in (("population", "150"), ("generations", "15")):
        field = form.find_element(By.NAME, name)
        field.clear()
        field.send_keys(value)
    driver.find_element(By.ID, "job-submit").click()
    wait_until(driver, lambda d: "/jobs/" in d.current_url)
    started = time.monotonic()
    # live: the page shows a running phase and generation before the job ends
    wait_until(driver, lambda d: ": generation " in d.find_element(By.ID, "job-phase").text, timeout=90)
    seen_running = driver.find_element(By.ID, "job-status").text
    wait_until(driver, lambda d: d.find_element(By.ID, "job-status").text == "succeeded", timeout=120)
    wait_until(driver, lambda d: d.find_elements(By.ID, "job-result-text"))
    assert "DLS baseline" in driver.find_element(By.ID, "job-result-text").text
    assert driver.find_element(By.ID, "job-progress").text == "generation 30 / 30 (all phases)"
    # the figure follows the events: it ends on the final version, having been redrawn on the way
    wait_until(driver, lambda d: d.find_element(By.ID, "convergence").get_attribute("data-version") == "end:succeeded")
    lags = driver.execute_script("return window.spacearmFigureLags")
    print(
        f"\njob page: status {seen_running!r} while generations streamed; {len(lags)} figure redraws, "
        f"lag from event to figure max {max(lags):.2f} s, median {sorted(lags)[len(lags) // 2]:.2f} s, "
        f"job {time.monotonic() - started:.1f} s"
    )
    assert seen_running in ("queued", "running") and len(lags) >= 3
    wait_until(driver, lambda d: d.execute_script(ALL_IMAGES_LOADED, "#convergence"))
    screenshot(driver, "04-job-page")

    driver.get(stack.url + "/")
    assert "succeeded" in driver.find_element(By.ID, "jobs").text
    assert len(driver.find_elements(By.CSS_SELECTOR, "#plans a")) >= 1
    screenshot(driver, "05-index-lists")


#: What each docs page shows per operation.
DOC_PAGES = {
    "docs": (".opblock", "Swagger UI"),
    "redoc": ('[data-section-id^="operation/"]', "ReDoc"),
}


def console_errors(drv: Any) -> list[str]:
    """The browser's console errors since the last call (CSP violations among them)."""
    return [entry["message"] for entry in drv.get_log("browser") if entry["level"] == "SEVERE"]


def test_api_docs_render_every_operation_offline(driver: Any, stack: Stack) -> None:
    """``/docs`` and ``/redoc`` load their assets from this server only (no CDN; the browser
    could not resolve one) under the pages' CSP (no inline script), and show every operation of
    the document. The one console error allowed is ReDoc's Redocly logo, hard-coded to Redocly's
    CDN and blocked by the CSP before any request."""
    from selenium.webdriver.common.by import By

    with stack.client() as c:
        doc = c.get("/openapi.json").json()
    operations = [op for item in doc["paths"].values() for op in item.values()]
    console_errors(driver)
    for page, (selector, title) in DOC_PAGES.items():
        driver.get(f"{stack.url}/{page}")
        assert title in driver.title
        wait_until(driver, lambda d, s=selector: len(d.find_elements(By.CSS_SELECTOR, s)) >= len(operations), timeout=60)
        text = driver.find_element(By.TAG_NAME, "body").text
        for op in operations:
            assert op["summary"] in text, (page, op["operationId"])
        screenshot(driver, f"06-{page}")
        resources = driver.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
        assert any("/docs/assets/" in r for r in resources) and any(r.endswith("/openapi.json") for r in resources)
        # ReDoc's logo: blocked by the CSP before any request, listed as a resource all the same
        logo = "https://cdn.redoc.ly/redoc/logo-mini.svg" if page == "redoc" else None
        assert [r for r in resources if not r.startswith(stack.url + "/") and r != logo] == []
        errors = [e for e in console_errors(driver) if logo is None or logo not in e]
        assert errors == [], errors


def element_text(drv: Any, element_id: str) -> str:
    """The text of an element, or "" (safe while the page changes under the test)."""
    text: str = drv.execute_script("const e = document.getElementById(arguments[0]); return e ? e.textContent : ''", element_id)
    return text


def canvas_pixels(element: Any) -> Any:
    """The element's pixels as an ``(h, w, 3)`` array (a screenshot of it)."""
    import io

    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(element.screenshot_as_png)).convert("RGB")).astype(int)


def test_3d_view_plays_the_motion(driver: Any, stack: Stack) -> None:
    """The 3D view of a plan (three.js, bundled and served by this server, under the pages' CSP):
    the canvas renders the scene, nothing is logged as an error, the time slider moves the arm
    (the image changes and the end effector moves), Play advances the time, and the page
    fetched only this server."""
    import numpy as np
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    with stack.client() as c:
        body = {"robot_id": "table1", "task": {**PAPER_TASK, "dt_s": 0.5}, "method": {"name": "adaptive"}}
        plan_id = c.post("/v1/plans", params={"fields": ""}, json=body).json()["id"]
    console_errors(driver)
    driver.get(f"{stack.url}/plans/{plan_id}/view")
    wait_until(driver, lambda d: d.execute_script("return document.body.dataset.viewReady"), timeout=60)
    assert driver.execute_script("return document.body.dataset.viewReady") == "1", driver.find_element(By.ID, "view-status").text
    canvas = driver.find_element(By.ID, "scene")
    time.sleep(0.5)  # a few animation frames
    first = canvas_pixels(canvas)
    background = np.array([0x0D, 0x1B, 0x2A])
    drawn = np.any(np.abs(first - background) > 12, axis=2)
    print(f"\n3D view: {drawn.mean():.1%} of the canvas drawn ({first.shape[1]} x {first.shape[0]} px)")
    assert 0.02 < drawn.mean() < 0.95  # the scene, not a blank (or failed) canvas
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 50  # shaded meshes, not one flat colour
    screenshot(driver, "07-view3d-start")

    tip0 = driver.execute_script("return window.spacearmView.tip()")
    slider = driver.find_element(By.ID, "time")
    frames = int(driver.execute_script("return window.spacearmView.frames"))
    slider.click()  # the middle of the track
    slider.send_keys(Keys.END)  # then the last frame, as a user would with the keyboard
    wait_until(driver, lambda d: d.execute_script("return window.spacearmView.frame") == frames - 1)
    assert driver.find_element(By.ID, "time-label").text.startswith("t = 15.00 s")
    time.sleep(0.3)
    last = canvas_pixels(canvas)
    changed = np.any(np.abs(last - first) > 24, axis=2).mean()
    tip1 = driver.execute_script("return window.spacearmView.tip()")
    print(
        f"3D view: the slider changed {changed:.1%} of the canvas; the tip moved {np.linalg.norm(np.subtract(tip1, tip0)):.3f} m"
    )
    assert changed > 0.002  # the arm moved on screen
    with stack.client() as c:
        ee = c.get(f"/v1/plans/{plan_id}", params={"fields": "trajectory"}).json()["trajectory"]["ee_position_m"]
    np.testing.assert_allclose(tip0, ee[0], atol=1e-4)
    np.testing.assert_allclose(tip1, ee[-1], atol=1e-4)
    screenshot(driver, "08-view3d-end")

    slider.send_keys(Keys.HOME)
    driver.find_element(By.ID, "play").click()
    wait_until(driver, lambda d: d.execute_script("return window.spacearmView.frame") > 2, timeout=20)
    assert driver.find_element(By.ID, "play").text == "Pause"
    driver.find_element(By.ID, "play").click()

    resources = driver.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert [r for r in resources if not r.startswith(stack.url + "/")] == []
    assert any("/static/three-" in r for r in resources) and any(r.endswith("/scene.json") for r in resources)
    errors = console_errors(driver)
    assert errors == [], errors


def test_compare_page_and_robot_upload(driver: Any, stack: Stack, tmp_path: Path) -> None:
    """Two plans compared (any figure, here the paper's Fig. 9), and a robot uploaded from a
    file and deleted again, through the page."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    from engine.model import urdf_preset_text

    with stack.client() as c:
        ids = [
            c.post("/v1/plans", params={"fields": ""}, json={"robot_id": "table1", "task": PAPER_TASK, "method": m}).json()["id"]
            for m in ({"name": "dls", "params": {"lambda": 0.05}}, {"name": "adaptive"})
        ]
    driver.get(f"{stack.url}/plans/compare?a={ids[0]}&b={ids[1]}")
    Select(driver.find_element(By.ID, "compare-figure")).select_by_value("joint-velocities")
    driver.find_element(By.ID, "compare-submit").click()
    # read in the page, not through an element found before the new page replaced it (stale)
    wait_until(
        driver,
        lambda d: (
            d.execute_script(ALL_IMAGES_LOADED, "#compare-image")
            and "figures/joint-velocities?ids=" in d.execute_script(COMPARE_SRC)
        ),
    )
    screenshot(driver, "09-compare")

    urdf = tmp_path / "arm7.urdf"
    urdf.write_text(urdf_preset_text("arm7"))
    driver.get(stack.url + "/")
    form = driver.find_element(By.ID, "robot-form")
    form.find_element(By.NAME, "file").send_keys(str(urdf))
    form.find_element(By.NAME, "end_effector_link").send_keys("tool0")
    form.find_element(By.NAME, "name").send_keys("uploaded arm")
    driver.find_element(By.ID, "robot-submit").click()
    wait_until(driver, lambda d: "uploaded arm" in element_text(d, "robots"))
    assert "uploaded arm" in [o.text for o in Select(driver.find_element(By.ID, "robot")).options]
    row = driver.find_element(By.XPATH, "//section[@id='robots']//tr[td[contains(., 'uploaded arm')]]")
    screenshot(driver, "10-robot-uploaded")
    row.find_element(By.CSS_SELECTOR, "button[data-delete]").click()
    driver.switch_to.alert.accept()  # the page asks first
    wait_until(driver, lambda d: "/#robots" in d.current_url and "uploaded arm" not in element_text(d, "robots"))
