"""The studio's page off loopback, in headless Chromium: opened once with the token in its URL,
it must keep the token in a cookie the page's script cannot read, drop it from the address, and
drag the arm; the same page without the token must be refused.

Usage: token_page.py URL_WITH_TOKEN OUTDIR. Prints one JSON line; exits 1 with a reason on the
first check that fails. Run by tests/studio.rs.
"""
import json
import sys
import urllib.request

from browser import chromium, drags_left_arm, fail, wait

URL, OUT = sys.argv[1], sys.argv[2]
BASE, TOKEN = URL.split("?token=")


def pose():
    req = urllib.request.Request(BASE.rstrip("/") + "/api/pose", headers={"Authorization": f"Bearer {TOKEN}"})
    with urllib.request.urlopen(req, timeout=10) as r:
        return json.loads(r.read())


driver = chromium()
result = {}
try:
    driver.get(BASE)
    text = driver.find_element("tag name", "body").text
    if "needs its token" not in text:
        fail(f"the page opened without the token: {text[:200]}")

    driver.get(URL)
    wait("the first state", lambda: driver.execute_script("return !!(window.studio && studio.state && studio.hello)"))
    result["address"] = driver.current_url
    if "token" in driver.current_url:
        fail(f"the token stayed in the address: {driver.current_url}")
    if TOKEN in driver.execute_script("return document.cookie"):
        fail("the page's script can read the token")
    cookies = {c["name"]: c for c in driver.get_cookies()}
    cookie = next((c for n, c in cookies.items() if n.startswith("marionette_studio_")), None)
    if not cookie or not cookie["httpOnly"] or cookie.get("sameSite") != "Strict":
        fail(f"the token's cookie: {cookie}")
    moved = drags_left_arm(driver, lambda: {s["name"]: s["goal_deg"] for s in pose()["servos"]})
    result["moved"] = moved
    if not moved:
        fail("the page with the token did not drag the arm")
    driver.save_screenshot(f"{OUT}/token.png")
finally:
    driver.quit()
print(json.dumps(result), flush=True)
