"""ROBOTIS's own Python SDK (`dynamixel-sdk` 4.1.0 from PyPI) as a client of a served chain:
checks of X-series behaviour as the e-manual gives it, each printed PASS/FAIL, then the pass
rate. Usage: sdk_check.py PORT PROFILE.toml [--json] [--sim] (--sim: the servos carry a load,
MuJoCo's).

Start the chain first: `marionette serve PROFILE` (or `marionette sim serve PROFILE ASF`).
Every check names what the e-manual expects; a FAIL is a difference of the virtual servo.
"""
import json
import sys
import time
import tomllib

from dynamixel_sdk import (COMM_SUCCESS, GroupBulkRead, GroupSyncRead, PacketHandler,
                           PortHandler)

PORT, PROFILE = sys.argv[1], sys.argv[2]
# Model numbers (e-manual, each model's control table, address 0).
MODEL_NUMBERS = {"XL330-M288": 1200, "XL430-W250": 1060, "XM430-W210": 1030,
                 "XM430-W350": 1020, "XH540-W270": 1100}
# Baud Rate register codes.
BAUD_CODES = {9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5,
              4_000_000: 6, 4_500_000: 7}
# Current Limit's factory value (e-manual; models without current sensing have none).
CURRENT_LIMITS = {"XL330-M288": 1750, "XM430-W210": 1193, "XM430-W350": 1193, "XH540-W270": 2047}
# Temperature Limit and Max/Min Voltage Limit factory values.
TEMPERATURE_LIMITS = {"XL330-M288": 70, "XL430-W250": 72, "XM430-W210": 80, "XM430-W350": 80,
                      "XH540-W270": 80}
VOLTAGE_LIMITS = {"XL330-M288": (70, 35), "XL430-W250": (140, 60), "XM430-W210": (160, 95),
                  "XM430-W350": (160, 95), "XH540-W270": (160, 95)}
# Protocol 2.0 status error numbers.
RANGE, LENGTH, ACCESS = 4, 5, 7

with open(PROFILE, "rb") as f:
    profile = tomllib.load(f)
servos = [(s["id"], s["model"]) for s in profile["servo"]]
ids = [i for i, _ in servos]
baud = profile["bus"]["baud"]

port = PortHandler(PORT)
port.openPort()
port.setBaudRate(57600)  # a pty ignores it
ph = PacketHandler(2.0)
results = []


def check(name, ok, detail=""):
    results.append((name, bool(ok), detail))
    print(f"{'PASS' if ok else 'FAIL'}  {name}" + (f"  ({detail})" if detail and not ok else ""), flush=True)


def error_of(result, error):
    return None if result != COMM_SUCCESS else (error & 0x7F)


first, second = ids[0], ids[1]
# Return Delay Time 0 first (EEPROM, torque off), so the checks run quickly.
for i in ids:
    ph.write1ByteTxRx(port, i, 64, 0)
    ph.write1ByteTxRx(port, i, 9, 0)

for i, model in servos:
    number, r, e = ph.ping(port, i)
    check(f"ping {i}: model number of {model}", r == COMM_SUCCESS and number == MODEL_NUMBERS.get(model),
          f"got {number}")
found, r = ph.broadcastPing(port)
check("broadcast ping finds every servo", r == COMM_SUCCESS and sorted(found) == sorted(ids), f"{sorted(found)}")

v, r, e = ph.read4ByteTxRx(port, first, 132)
check("read Present Position", r == COMM_SUCCESS and e == 0 and 0 <= v < 4096, f"{v} {r} {e}")
v, r, e = ph.read1ByteTxRx(port, first, 8)
check("Baud Rate register holds the line's baud", r == COMM_SUCCESS and v == BAUD_CODES.get(baud), f"{v} for {baud}")
v, r, e = ph.read1ByteTxRx(port, first, 122)
check("Moving reads 0 at rest", r == COMM_SUCCESS and v == 0, f"{v}")
t1, r1, _ = ph.read2ByteTxRx(port, first, 120)
time.sleep(0.05)
t2, r2, _ = ph.read2ByteTxRx(port, first, 120)
check("Realtime Tick advances", r1 == r2 == COMM_SUCCESS and t1 != t2, f"{t1} {t2}")

for addr, size, value, name in [(8, 1, 9, "Baud Rate 9"), (11, 1, 2, "Operating Mode 2"),
                                (48, 4, 4096, "Max Position Limit 4096"), (64, 1, 2, "Torque Enable 2"),
                                (68, 1, 3, "Status Return Level 3"), (24, 4, 1024, "Moving Threshold 1024"),
                                (36, 2, 886, "PWM Limit 886"), (112, 4, 32768, "Profile Velocity 32768")]:
    write = {1: ph.write1ByteTxRx, 2: ph.write2ByteTxRx, 4: ph.write4ByteTxRx}[size]
    r, e = write(port, first, addr, value)
    check(f"out of range: {name} answers Data Range Error", error_of(r, e) == RANGE, f"{r} {e}")
r, e = ph.write1ByteTxRx(port, first, 69, 1)
check("write to read-only Registered Instruction answers Access Error", error_of(r, e) == ACCESS, f"{r} {e}")
r, e = ph.write2ByteTxRx(port, first, 116, 2048)
check("2-byte write to 4-byte Goal Position answers Data Length Error", error_of(r, e) == LENGTH, f"{r} {e}")
ph.write1ByteTxRx(port, first, 64, 1)
r, e = ph.write1ByteTxRx(port, first, 11, 3)
check("EEPROM write with torque on answers Access Error", error_of(r, e) == ACCESS, f"{r} {e}")
pos, _, _ = ph.read4ByteTxRx(port, first, 132)
r, e = ph.write4ByteTxRx(port, first, 116, pos)
check("Goal Position write with torque on", r == COMM_SUCCESS and e == 0, f"{r} {e}")
ph.write1ByteTxRx(port, first, 64, 0)

g = GroupSyncRead(port, ph, 132, 4)
for i in ids:
    g.addParam(i)
r = g.txRxPacket()
check("Sync Read of every servo", r == COMM_SUCCESS and all(g.isAvailable(i, 132, 4) for i in ids), f"{r}")
r = g.fastSyncRead()
check("Fast Sync Read of every servo", r == COMM_SUCCESS and all(g.isAvailable(i, 132, 4) for i in ids), f"{r}")
b = GroupBulkRead(port, ph)
b.addParam(first, 132, 4)
b.addParam(second, 126, 2)
r = b.txRxPacket()
check("Bulk Read of two servos, two items", r == COMM_SUCCESS and b.isAvailable(first, 132, 4) and b.isAvailable(second, 126, 2), f"{r}")
r = b.fastBulkRead() if hasattr(b, "fastBulkRead") else -1
check("Fast Bulk Read of two servos", r == COMM_SUCCESS, f"{r}")

r, e = ph.regWriteTxRx(port, first, 112, 4, [10, 0, 0, 0])
v, _, _ = ph.read4ByteTxRx(port, first, 112)
reg, _, _ = ph.read1ByteTxRx(port, first, 69)
check("Reg Write is taken, held until Action (Registered Instruction 1)",
      r == COMM_SUCCESS and e == 0 and v != 10 and reg == 1, f"{r} {e} {v} {reg}")
ph.action(port, first)
time.sleep(0.01)
v, _, _ = ph.read4ByteTxRx(port, first, 112)
check("Action applies the registered write", v == 10, f"{v}")

# Indirect Address 1 at the Model Number's low byte: Indirect Data 1 reads it.
r, e = ph.write2ByteTxRx(port, first, 168, 0)
v, r2, e2 = ph.read1ByteTxRx(port, first, 224)
model = dict(servos)[first]
check("Indirect Data 1 reads the byte Indirect Address 1 points at",
      r == COMM_SUCCESS and e == 0 and r2 == COMM_SUCCESS and v == MODEL_NUMBERS[model] & 0xFF, f"{r} {e} {r2} {v}")

ph.write1ByteTxRx(port, first, 68, 1)
v, r, e = ph.read4ByteTxRx(port, first, 132)
check("Status Return Level 1: a read is answered", r == COMM_SUCCESS, f"{r}")
r, e = ph.write4ByteTxRx(port, first, 112, 0)
check("Status Return Level 1: a write is not", r != COMM_SUCCESS, f"{r}")
ph.write1ByteTxOnly(port, first, 68, 2)
time.sleep(0.01)
r, e = ph.reboot(port, first)
check("Reboot answered at Status Return Level 2", r == COMM_SUCCESS, f"{r}")
time.sleep(0.1)
ph.write1ByteTxRx(port, first, 68, 1)
r, e = ph.reboot(port, first)
check("Reboot not answered at Status Return Level 1", r != COMM_SUCCESS, f"{r}")
time.sleep(0.1)
ph.write1ByteTxRx(port, first, 68, 2)

# Profile Velocity (0.229 rpm units) sets the speed of a move: 20 units are 312.6 ticks/s, so
# 180 ticks take 0.58 s (Profile Acceleration 0: no ramp).
ph.write4ByteTxRx(port, first, 108, 0)
ph.write4ByteTxRx(port, first, 112, 20)
ph.write1ByteTxRx(port, first, 64, 1)
time.sleep(0.2)
start_pos, _, _ = ph.read4ByteTxRx(port, first, 132)
lo, _, _ = ph.read4ByteTxRx(port, first, 52)
hi, _, _ = ph.read4ByteTxRx(port, first, 48)
step = 180 if start_pos + 200 <= hi else -180
ph.write4ByteTxRx(port, first, 116, start_pos + step)
began = time.monotonic()
pwm_seen, moving_seen, took = 0, 0, None
while time.monotonic() - began < 3.0:
    pos, _, _ = ph.read4ByteTxRx(port, first, 132)
    pwm, _, _ = ph.read2ByteTxRx(port, first, 124)
    mov, _, _ = ph.read1ByteTxRx(port, first, 122)
    pwm_seen = max(pwm_seen, abs(pwm - 65536 if pwm >= 32768 else pwm))
    moving_seen |= mov
    pos = pos - (1 << 32) if pos >= 1 << 31 else pos
    if took is None and abs(pos - start_pos) >= 0.9 * abs(step):
        took = time.monotonic() - began
        break
    time.sleep(0.005)
check("Profile Velocity 20: a 180-tick move takes about 0.52 s to 90 %",
      took is not None and 0.35 <= took <= 0.8, f"{took}")
check("Moving reads 1 during a move", moving_seen == 1, f"{moving_seen}")
check("Present PWM is not zero during a move", pwm_seen > 0, f"{pwm_seen}")
ph.write4ByteTxRx(port, first, 112, 0)
if "--sim" in sys.argv:
    # Gravity loads the rig: with torque on, some servo draws current to hold it.
    for i in ids:
        ph.write1ByteTxRx(port, i, 64, 1)
    time.sleep(0.3)
    currents = []
    for i in ids:
        c, _, _ = ph.read2ByteTxRx(port, i, 126)
        currents.append(c - 65536 if c >= 32768 else c)
    check("Present Current under load: some servo draws current", any(abs(c) >= 5 for c in currents),
          f"{currents}")
    for i in ids[1:]:
        ph.write1ByteTxRx(port, i, 64, 0)

ph.write1ByteTxRx(port, first, 98, 1)
ph.write1ByteTxRx(port, first, 64, 1)
time.sleep(0.1)
v, r, _ = ph.read1ByteTxRx(port, first, 98)
check("Bus Watchdog expires to -1 (255)", r == COMM_SUCCESS and v == 255, f"{v}")
pos, _, _ = ph.read4ByteTxRx(port, first, 132)
r, e = ph.write4ByteTxRx(port, first, 116, pos)
check("a goal write after watchdog expiry answers Data Range Error", error_of(r, e) == RANGE, f"{r} {e}")
ph.write1ByteTxRx(port, first, 98, 0)
ph.write1ByteTxRx(port, first, 64, 0)

ph.factoryReset(port, 254, 0xFF)
time.sleep(0.1)
_, r, _ = ph.ping(port, second)
check("broadcast Factory Reset 0xFF is ignored (firmware 42+)", r == COMM_SUCCESS, f"{r}")
ph.write1ByteTxRx(port, second, 64, 0)
r, e = ph.factoryReset(port, second, 0x02)
time.sleep(0.1)
_, r2, _ = ph.ping(port, second)
v, _, _ = ph.read1ByteTxRx(port, second, 8)
check("Factory Reset 0x02 keeps id and baud", r == COMM_SUCCESS and r2 == COMM_SUCCESS and v == BAUD_CODES.get(baud), f"{r} {r2} {v}")

# Factory Reset 0x02 put every other item back to its factory value.
second_model = dict(servos)[second]
for addr, size, value, name in [(9, 1, 250, "Return Delay Time 250"), (11, 1, 3, "Operating Mode 3"),
                                (24, 4, 10, "Moving Threshold 10"), (36, 2, 885, "PWM Limit 885"),
                                (48, 4, 4095, "Max Position Limit 4095"), (52, 4, 0, "Min Position Limit 0"),
                                (68, 1, 2, "Status Return Level 2"),
                                (31, 1, TEMPERATURE_LIMITS[second_model], "Temperature Limit"),
                                (32, 2, VOLTAGE_LIMITS[second_model][0], "Max Voltage Limit"),
                                (34, 2, VOLTAGE_LIMITS[second_model][1], "Min Voltage Limit")] + (
        [(38, 2, CURRENT_LIMITS[second_model], f"Current Limit {CURRENT_LIMITS[second_model]}")]
        if second_model in CURRENT_LIMITS else []):
    read = {1: ph.read1ByteTxRx, 2: ph.read2ByteTxRx, 4: ph.read4ByteTxRx}[size]
    v, r, _ = read(port, second, addr)
    check(f"factory value after reset: {name}", r == COMM_SUCCESS and v == value, f"{v}")

passed = sum(ok for _, ok, _ in results)
print(f"checks: {passed} of {len(results)} as the e-manual says")
if "--json" in sys.argv:
    print(json.dumps({"passed": passed, "total": len(results),
                      "failed": [n for n, ok, _ in results if not ok]}))
