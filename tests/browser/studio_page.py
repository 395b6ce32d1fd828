"""Drives `marionette studio`'s page in headless Chromium through ChromeDriver (WebDriver).

Usage: studio_page.py URL OUTDIR. Prints one JSON line of what it measured; exits 1 with a
reason on the first check that fails. Run by tests/studio.rs.
"""
import json
import sys
import time
import urllib.request

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

URL, OUT = sys.argv[1], sys.argv[2]


def fail(reason):
    print(f"FAIL: {reason}", flush=True)
    sys.exit(1)


def api(path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(URL.rstrip("/") + path, data=data, method="POST" if data else "GET")
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())


def wait(what, check, timeout=15.0):
    end = time.time() + timeout
    while time.time() < end:
        got = check()
        if got:
            return got
        time.sleep(0.05)
    fail(f"timed out waiting for {what}")


options = webdriver.ChromeOptions()
options.binary_location = "/usr/bin/chromium"
for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-dev-shm-usage", "--window-size=1280,800"):
    options.add_argument(flag)
options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
result = {}
try:
    driver.get(URL)
    wait("the first state", lambda: driver.execute_script("return !!(window.studio && studio.state && studio.hello)"))
    time.sleep(0.5)
    errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    errors += driver.execute_script("return window.studioErrors")
    if errors:
        fail(f"console errors on load: {errors}")
    driver.save_screenshot(f"{OUT}/loaded.png")

    before = api("/api/pose")
    if before["solver"] != "analytic":
        fail(f"default solver {before['solver']}")
    goals_before = {s["name"]: s["goal_deg"] for s in before["servos"]}
    tip_before = before["tips"]["lradius"]

    canvas = driver.find_element(By.ID, "view")
    size = canvas.size

    def drag(name, dx, dy, steps, pause):
        h = driver.execute_script("return studio.handleScreen(arguments[0])", name)
        if not h:
            fail(f"no handle {name}")
        chain = ActionChains(driver, duration=0)
        chain.move_to_element_with_offset(canvas, int(h["x"] - size["width"] / 2), int(h["y"] - size["height"] / 2))
        chain.click_and_hold()
        for _ in range(steps):
            chain.move_by_offset(dx, dy)
            chain.pause(pause)
        chain.release()
        t0 = time.time()
        chain.perform()
        return time.time() - t0

    # The left hand's handle dragged in towards the shoulder and up (the rest pose holds the arm
    # straight out: any way out is beyond reach), for about two seconds.
    frames0 = driver.execute_script("return studio.framesWhileDragging")
    seconds = drag("lradius", -2, -1, 60, 0.03)
    frames = driver.execute_script("return studio.framesWhileDragging") - frames0
    result["drag_fps"] = frames / seconds
    result["fps"] = driver.execute_script("return studio.fps")
    time.sleep(0.6)
    after = api("/api/pose")
    moved = sum((a - b) ** 2 for a, b in zip(after["tips"]["lradius"], tip_before)) ** 0.5
    result["hand_moved_units"] = moved
    result["residual"] = after["residual"]
    if moved < 1.0:
        fail(f"the left hand moved {moved} units")
    if not after["residual"] < 1e-3:
        fail(f"residual {after['residual']} after the drag")
    changed = [n for n, g in goals_before.items()
               if g is not None and abs(next(s for s in after["servos"] if s["name"] == n)["goal_deg"] - g) > 0.5]
    result["servos_moved"] = changed
    if not any(n.startswith("lhumerus") or n.startswith("lradius") for n in changed):
        fail(f"no left-arm goal register changed: {changed}")
    driver.save_screenshot(f"{OUT}/dragged.png")

    # Switching the solver in the page changes the reported solver.
    Select(driver.find_element(By.ID, "method")).select_by_value("ccd")
    wait("ccd reported", lambda: api("/api/pose")["solver"] == "ccd")
    wait("ccd in the page", lambda: driver.execute_script("return studio.state.report.solver") == "ccd")

    # Compare mode: CCD against the Jacobian transpose on the same drag, two poses drawn.
    Select(driver.find_element(By.ID, "compare")).select_by_value("jt")
    wait("the ghost", lambda: driver.execute_script("return !!studio.state.ghost"))
    drag("lradius", -3, 2, 25, 0.03)
    time.sleep(0.5)
    ghost = driver.execute_script("return studio.state.ghost.report")
    primary = driver.execute_script("return studio.state.report")
    result["compare"] = {"primary": primary, "ghost": ghost}
    driver.save_screenshot(f"{OUT}/compare.png")

    stats = api("/api/stats")
    result["drag_to_write_us"] = stats["drag_to_write_us"]
    result["receipt_to_write_us"] = stats["receipt_to_write_us"]
    result["loop"] = stats["loop"]
    if stats["drag_to_write_us"]["n"] < 5:
        fail(f"few drags reached the bus: {stats['drag_to_write_us']}")
    errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    errors += driver.execute_script("return window.studioErrors")
    if errors:
        fail(f"console errors: {errors}")
finally:
    driver.quit()
print(json.dumps(result), flush=True)
