"""Drives `marionette studio`'s page in headless Chromium through ChromeDriver (WebDriver).

Usage: studio_page.py URL OUTDIR. Prints one JSON line of what it measured; exits 1 with a
reason on the first check that fails. Run by tests/studio.rs.
"""
import json
import sys
import time

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from browser import api as api_at, chromium, console_errors, drag, fail, wait

URL, OUT = sys.argv[1], sys.argv[2]


def api(path, body=None):
    return api_at(URL, path, body)


driver = chromium()
result = {}
try:
    driver.get(URL)
    wait("the first state", lambda: driver.execute_script("return !!(window.studio && studio.state && studio.hello)"))
    time.sleep(0.5)
    errors = console_errors(driver)
    if errors:
        fail(f"console errors on load: {errors}")
    driver.save_screenshot(f"{OUT}/loaded.png")

    before = api("/api/pose")
    if before["solver"] != "analytic":
        fail(f"default solver {before['solver']}")
    goals_before = {s["name"]: s["goal_deg"] for s in before["servos"]}
    tip_before = before["tips"]["lradius"]

    # The left hand's handle dragged in towards the shoulder and up (the rest pose holds the arm
    # straight out: any way out is beyond reach), for about two seconds.
    frames0 = driver.execute_script("return studio.framesWhileDragging")
    seconds = drag(driver, "lradius", -2, -1, 60, 0.03)
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
    drag(driver, "lradius", -3, 2, 25, 0.03)
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
    errors = console_errors(driver)
    if errors:
        fail(f"console errors: {errors}")
finally:
    driver.quit()
print(json.dumps(result), flush=True)
