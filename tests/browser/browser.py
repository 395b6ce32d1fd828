"""What the studio's browser tests share: headless Chromium through ChromeDriver, the studio's
JSON API, waiting, and dragging a handle on the page's canvas."""
import json
import sys
import time
import urllib.request

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By


def fail(reason):
    print(f"FAIL: {reason}", flush=True)
    sys.exit(1)


def api(url, path, body=None):
    """GET (or POST a JSON body) to the studio at `url`; the decoded JSON answer."""
    data = None if body is None else json.dumps(body).encode()
    headers = {} if data is None else {"Content-Type": "application/json"}
    req = urllib.request.Request(url.rstrip("/") + path, data=data, headers=headers,
                                 method="POST" if data else "GET")
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


def chromium(*flags):
    """Headless Chromium with the flags this closed machine needs, and `flags`."""
    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", "--window-size=1280,800", *flags):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)


def drag(driver, name, dx, dy, steps, pause):
    """Drags effector `name`'s handle on the studio page by (dx, dy) pixels `steps` times;
    the seconds it took."""
    canvas = driver.find_element(By.ID, "view")
    size = canvas.size
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


def drags_left_arm(driver, goals):
    """Once the page has its state, drags the left hand's handle in and up; the left-arm servos
    whose goal (from `goals()`, name → degrees) moved more than half a degree."""
    wait("the first state", lambda: driver.execute_script("return !!(window.studio && studio.state && studio.hello)"))
    time.sleep(0.5)
    before = goals()
    drag(driver, "lradius", -2, -1, 40, 0.03)
    time.sleep(0.6)
    after = goals()
    return [n for n in after if (n.startswith("lhumerus") or n.startswith("lradius"))
            and abs(after[n] - before[n]) > 0.5]


def console_errors(driver):
    errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    return errors + (driver.execute_script("return window.studioErrors") or [])
