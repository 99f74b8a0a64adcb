#!/usr/bin/env python3
"""A ground station's view of alfd, with pymavlink: listen on a UDP port the system picks
(printed as `PORT <n>`), then wait for alfd's HEARTBEAT and check that it lists as a camera
component (MAV_TYPE_CAMERA from component 100) of the expected system; check that alfd also
asks for time synchronisation. Prints one JSON line with what it saw; exit 0 only if it holds."""
import json
import os
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

expected_sysid = int(sys.argv[1]) if len(sys.argv) > 1 else 1
conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", dialect="common", source_system=255)
print("PORT", conn.port.getsockname()[1], flush=True)

seen = {"heartbeats": 0, "timesync_requests": 0}
deadline = time.time() + 30
while time.time() < deadline and not (seen["heartbeats"] >= 2 and seen["timesync_requests"] >= 1):
    msg = conn.recv_match(blocking=True, timeout=1.0)
    if msg is None:
        continue
    t = msg.get_type()
    if t == "HEARTBEAT":
        seen["heartbeats"] += 1
        seen.update(
            system=msg.get_srcSystem(),
            component=msg.get_srcComponent(),
            type=msg.type,
            autopilot=msg.autopilot,
            mavlink2=msg.get_msgbuf()[0] == 0xFD,
        )
        # Answer like a ground station does, so alfd has a peer.
        conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    elif t == "TIMESYNC" and msg.tc1 == 0:
        seen["timesync_requests"] += 1

ok = (
    seen["heartbeats"] >= 2
    and seen.get("type") == mavutil.mavlink.MAV_TYPE_CAMERA
    and seen.get("component") == mavutil.mavlink.MAV_COMP_ID_CAMERA
    and seen.get("system") == expected_sysid
    and seen.get("autopilot") == mavutil.mavlink.MAV_AUTOPILOT_INVALID
    and seen["timesync_requests"] >= 1
)
print(json.dumps({"ok": ok, **seen}), flush=True)
sys.exit(0 if ok else 1)
