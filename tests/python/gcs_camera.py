#!/usr/bin/env python3
"""A ground station watching alfd's camera, with pymavlink: listen on a UDP port the system picks
(printed as `PORT <n>`), answer heartbeats as a GCS, and once the camera (component 100,
MAV_TYPE_CAMERA, of the expected system) is heard, ask it for CAMERA_INFORMATION and
STORAGE_INFORMATION (MAV_CMD_REQUEST_MESSAGE, retried at most once a second until answered).
Collect acks, both informations, every CAMERA_IMAGE_CAPTURED, the ALF_SPC/ALF_OCC named values
and status texts. Stop once there are enough captures and both informations, at the deadline,
or when stdin closes. Prints `RESULT <json>`; exit 0 only if the condition held.

usage: gcs_camera.py [SYSID=1] [MIN_IMAGES=3] [DEADLINE_S=60]"""
import json
import math
import os
import sys
import threading
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

mav = mavutil.mavlink
expected_sysid = int(sys.argv[1]) if len(sys.argv) > 1 else 1
min_images = int(sys.argv[2]) if len(sys.argv) > 2 else 3
deadline_s = float(sys.argv[3]) if len(sys.argv) > 3 else 60.0
CAMERA_COMPONENT = mav.MAV_COMP_ID_CAMERA  # 100
WANTED = {
    mav.MAVLINK_MSG_ID_CAMERA_INFORMATION: "camera_information",  # 259
    mav.MAVLINK_MSG_ID_STORAGE_INFORMATION: "storage_information",  # 261
}

conn = mavutil.mavlink_connection(
    "udpin:127.0.0.1:0",
    dialect="common",
    source_system=255,
    source_component=mav.MAV_COMP_ID_MISSIONPLANNER,
)
print("PORT", conn.port.getsockname()[1], flush=True)

# The test closes stdin to stop us.
stdin_closed = threading.Event()


def watch_stdin():
    # The raw descriptor, not sys.stdin: a daemon thread blocked in a buffered read aborts the
    # interpreter at exit.
    try:
        while os.read(0, 4096):
            pass
    except OSError:
        pass
    stdin_closed.set()


threading.Thread(target=watch_stdin, daemon=True).start()


def clean(msg):
    """A message's fields as JSON-friendly values (byte arrays as text)."""
    d = msg.to_dict()
    d.pop("mavpackettype", None)
    for k, v in d.items():
        if isinstance(v, (bytes, bytearray)):
            d[k] = v.split(b"\0")[0].decode("utf-8", "replace")
        elif k in ("vendor_name", "model_name") and isinstance(v, list):
            d[k] = bytes(v).split(b"\0")[0].decode("utf-8", "replace")
    return d


start = time.monotonic()
result = {
    "system": expected_sysid,
    "camera_seen": False,
    "heartbeats": {},  # "sys/comp" -> {"count", "type", "autopilot"}
    "requests_sent": {name: 0 for name in WANTED.values()},
    "acks": [],
    "camera_information": None,
    "storage_information": None,
    "images": [],
    "named_values": {},  # name -> {"count", "last", "time_boot_ms"}
    "statustexts": [],
}
last_request = {}  # message id -> monotonic time of the last request
last_heartbeat_sent = None


def done():
    return (
        len(result["images"]) >= min_images
        and result["camera_information"] is not None
        and result["storage_information"] is not None
    )


reason = "deadline"
while True:
    now = time.monotonic()
    if done():
        reason = "done"
        break
    if now - start >= deadline_s:
        reason = "deadline"
        break
    if stdin_closed.is_set():
        reason = "stdin closed"
        break

    # Requests for what is still missing, at most once a second each; `confirmation` counts
    # retransmissions as MAVLink asks.
    if result["camera_seen"]:
        for msg_id, name in WANTED.items():
            if result[name] is None and now - last_request.get(msg_id, -1e9) >= 1.0:
                conn.mav.command_long_send(
                    expected_sysid,
                    CAMERA_COMPONENT,
                    mav.MAV_CMD_REQUEST_MESSAGE,
                    min(result["requests_sent"][name], 255),
                    msg_id,
                    0, 0, 0, 0, 0, 0,
                )
                result["requests_sent"][name] += 1
                last_request[msg_id] = now

    msg = conn.recv_match(blocking=True, timeout=0.2)
    if msg is None:
        continue
    t = msg.get_type()
    src = (msg.get_srcSystem(), msg.get_srcComponent())
    if t == "BAD_DATA":
        continue
    if t == "HEARTBEAT":
        key = "%d/%d" % src
        hb = result["heartbeats"].setdefault(key, {"count": 0})
        hb.update(count=hb["count"] + 1, type=msg.type, autopilot=msg.autopilot)
        if src == (expected_sysid, CAMERA_COMPONENT) and msg.type == mav.MAV_TYPE_CAMERA:
            result["camera_seen"] = True
        # Answer like a ground station does (once a second), so the vehicle has a peer.
        if last_heartbeat_sent is None or now - last_heartbeat_sent >= 1.0:
            conn.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            last_heartbeat_sent = now
    elif t == "COMMAND_ACK":
        if msg.target_system in (0, 255):
            result["acks"].append(
                {
                    "system": src[0],
                    "component": src[1],
                    "command": msg.command,
                    "result": msg.result,
                    "t_unix": time.time(),
                }
            )
    elif src[0] != expected_sysid:
        continue
    elif t == "CAMERA_INFORMATION":
        result["camera_information"] = dict(clean(msg), component=src[1])
    elif t == "STORAGE_INFORMATION":
        result["storage_information"] = dict(clean(msg), component=src[1])
    elif t == "CAMERA_IMAGE_CAPTURED":
        result["images"].append(
            {
                "component": src[1],
                "image_index": msg.image_index,
                "lat": msg.lat,
                "lon": msg.lon,
                "relative_alt": msg.relative_alt,
                "capture_result": msg.capture_result,
                "file_url": msg.file_url,
                "time_boot_ms": msg.time_boot_ms,
                "t_unix": time.time(),
            }
        )
    elif t == "NAMED_VALUE_FLOAT" and msg.name in ("ALF_SPC", "ALF_OCC"):
        nv = result["named_values"].setdefault(msg.name, {"count": 0})
        nv.update(count=nv["count"] + 1, last=msg.value, time_boot_ms=msg.time_boot_ms)
    elif t == "STATUSTEXT":
        result["statustexts"].append({"component": src[1], "severity": msg.severity, "text": msg.text})

def json_safe(v):
    """NaN and the infinities as null: MAVLink uses NaN for "unknown" (CAMERA_INFORMATION's
    focal length and sensor size), and json.dumps would write it as `NaN`, which is not JSON."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, list):
        return [json_safe(x) for x in v]
    return v


ok = done()
result.update(ok=ok, reason=reason, elapsed_s=round(time.monotonic() - start, 3))
print("RESULT " + json.dumps(json_safe(result), allow_nan=False), flush=True)
sys.exit(0 if ok else 1)
