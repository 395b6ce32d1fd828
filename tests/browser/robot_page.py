"""The studio with a robot's profile in a real browser: the page draws the robot beside the
human (its links, soles, support polygon, centre of mass and ZMP), and dragging the left hand
moves the robot's left arm. Prints one JSON line; screenshots in the directory given."""
import json
import sys
import time

from browser import api, chromium, drag, fail, wait

url, out = sys.argv[1], sys.argv[2]
driver = chromium()
try:
    driver.get(url)
    wait("the robot drawn", lambda: driver.execute_script(
        "return window.studio && studio.state && studio.state.robot && studio.robotDrawn"))
    time.sleep(0.5)
    driver.save_screenshot(f"{out}/robot.png")
    links = driver.execute_script("return studio.robotDrawn")
    state = driver.execute_script("return studio.state.robot")
    before = {s["name"]: s["present_deg"] for s in api(url, "/api/pose")["servos"]}
    drag(driver, "lradius", -2, -1, 40, 0.03)
    time.sleep(0.8)
    after = {s["name"]: s["present_deg"] for s in api(url, "/api/pose")["servos"]}
    driver.save_screenshot(f"{out}/robot_dragged.png")
    moved = [n for n in after if n.startswith("l_") and before[n] is not None and after[n] is not None
             and abs(after[n] - before[n]) > 0.5]
    if links < 20:
        fail(f"{links} robot links drawn")
    if not any(n.startswith("l_sho") or n == "l_el" for n in moved):
        fail(f"the robot's left arm did not move: {moved}")
    print(json.dumps({"links": links, "planted": [s["planted"] for s in state["soles"]],
                      "support": len(state["support"]), "moved": moved}))
finally:
    driver.quit()
