"""A hostile page against `marionette studio`, in headless Chromium through ChromeDriver.

Usage: hostile_page.py STUDIO_URL OUTDIR. A second HTTP server on another port and another host
name (another origin, another site) serves a page that tries what any site the user visits could:
a no-cors text/plain POST, a text/plain form POST, a JSON fetch (preflighted) and a WebSocket to
the studio. A DNS-rebinding name (Chromium maps rebind.example to 127.0.0.1) then loads the
studio under a foreign Host. None of it may change a goal or present position, the studio must
keep running, and the real page must still drag the arm. Prints one JSON line of what it saw;
exits 1 with a reason on the first check that fails. Run by tests/studio.rs.
"""
import json
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import urlsplit

from browser import api as api_at, chromium, drags_left_arm, fail, wait

URL, OUT = sys.argv[1], sys.argv[2]
STUDIO = URL.rstrip("/")
PORT = urlsplit(URL).port

ATTACK = """<!doctype html><title>cute cats</title>
<iframe name="sink" style="display:none"></iframe>
<form id="form" method="POST" action="STUDIO/api/target" enctype="text/plain" target="sink">
<input name='{"effector":"lradius","position":[5,15,5],"pad":"' value='"}'></form>
<script>
const S = "STUDIO";
const body = JSON.stringify({effector: "lradius", position: [5, 15, 5]});
window.results = {};
const settle = (ms) => new Promise((r) => setTimeout(r, ms));
async function attack() {
  try {
    await fetch(S + "/api/target", {method: "POST", mode: "no-cors",
      headers: {"Content-Type": "text/plain"}, body});
    results.no_cors_post = "sent (opaque answer)";
  } catch (e) { results.no_cors_post = "failed: " + e; }
  try {
    const r = await fetch(S + "/api/target", {method: "POST",
      headers: {"Content-Type": "application/json"}, body});
    results.json_fetch = "answered " + r.status;
  } catch (e) { results.json_fetch = "blocked: " + e; }
  try {
    const r = await fetch(S + "/api/pose");
    results.read_pose = "read " + (await r.text()).length + " bytes";
  } catch (e) { results.read_pose = "blocked: " + e; }
  document.getElementById("form").submit();
  results.form_post = "submitted";
  await settle(500);
  results.websocket = await new Promise((done) => {
    const ws = new WebSocket(S.replace("http", "ws") + "/ws");
    ws.onopen = () => {
      ws.send(JSON.stringify({type: "drag", effector: "lradius", position: [5, 15, 5]}));
      setTimeout(() => done("OPEN: a drag sent"), 500);
    };
    ws.onerror = () => done("refused");
    setTimeout(() => done("no answer"), 5000);
  });
  window.done = true;
}
attack();
</script>""".replace("STUDIO", STUDIO)


class Attacker(BaseHTTPRequestHandler):
    def do_GET(self):
        page = ATTACK.encode()
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(page)))
        self.end_headers()
        self.wfile.write(page)

    def log_message(self, *args):
        pass


def api(path, body=None):
    return api_at(URL, path, body)


def positions():
    return {s["name"]: (s["goal_deg"], s["present_deg"]) for s in api("/api/pose")["servos"]}


attacker = ThreadingHTTPServer(("127.0.0.1", 0), Attacker)
threading.Thread(target=attacker.serve_forever, daemon=True).start()
evil = f"http://localhost:{attacker.server_address[1]}/"

driver = chromium("--host-resolver-rules=MAP rebind.example 127.0.0.1")
result = {"attacker": evil}
try:
    before = positions()
    stats0 = api("/api/stats")

    driver.get(evil)
    wait("the attack to finish", lambda: driver.execute_script("return window.done === true"), 20)
    result["attempts"] = driver.execute_script("return window.results")
    if result["attempts"]["websocket"].startswith("OPEN"):
        fail(f"the foreign page's WebSocket was accepted: {result['attempts']}")
    if result["attempts"]["json_fetch"].startswith("answered"):
        fail(f"the foreign page's JSON fetch was answered: {result['attempts']}")
    if result["attempts"]["read_pose"].startswith("read"):
        fail(f"the foreign page read the pose: {result['attempts']}")
    driver.save_screenshot(f"{OUT}/hostile.png")

    # DNS rebinding: the studio under a name the attacker controls, same-origin to the page.
    driver.get(f"http://rebind.example:{PORT}/")
    text = driver.find_element("tag name", "body").text
    if "is not a name of this studio" not in text:
        fail(f"the studio answered under a foreign name: {text[:200]}")
    status = driver.execute_async_script(
        """const done = arguments[arguments.length - 1];
        fetch("/api/target", {method: "POST", headers: {"Content-Type": "application/json"},
          body: JSON.stringify({effector: "lradius", position: [5, 15, 5]})})
          .then((r) => done(r.status), (e) => done("failed: " + e));""")
    result["rebinding_post"] = status
    if status != 403:
        fail(f"a POST under the rebinding name answered {status}")

    time.sleep(0.5)
    after = positions()
    moved = {n: (before[n], after[n]) for n in before
             if abs(after[n][0] - before[n][0]) > 1e-9 or abs(after[n][1] - before[n][1]) > 0.01}
    if moved:
        fail(f"servos moved: {moved}")
    stats1 = api("/api/stats")
    refused = {k: stats1["refused"][k] - stats0["refused"][k] for k in stats1["refused"]}
    result["refused"] = refused
    # The no-cors POST, the form, the preflight and the WebSocket by Origin; the page and the
    # POST under the rebinding name by Host.
    if refused["origin"] < 4 or refused["host"] < 2:
        fail(f"the studio did not see every attempt: {refused}")
    if stats1["loop"]["ticks"] <= stats0["loop"]["ticks"]:
        fail("the loop stopped")

    # The user's own page still drags the arm.
    driver.get(URL)
    arm = drags_left_arm(driver, lambda: {n: p[0] for n, p in positions().items()})
    result["own_page_moved"] = arm
    if not arm:
        fail("the studio's own page no longer drags the left arm")
    driver.save_screenshot(f"{OUT}/own-page-after-attack.png")
finally:
    driver.quit()
    attacker.shutdown()
print(json.dumps(result), flush=True)
