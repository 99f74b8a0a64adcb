#!/usr/bin/env python3
"""A MAVSDK ground station (system 245, `pip install mavsdk`, the native binding >= 4) for
alfd's camera, driven by tests/mavsdk_camera.rs: it listens on a UDP port of its own
(printed as `PORT <n>`), where firmware-sim forwards the vehicle's link; lists the camera,
reads its information and storage, takes PHOTOS photos and follows the capture_info stream.
Ends with one `RESULT <json>` line, after the photos and the captures' stream went quiet, at
DEADLINE_S, or when stdin closes.

usage: mavsdk_camera.py PHOTOS DEADLINE_S
"""

import json
import select
import socket
import sys
import threading
import time

from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera, CameraError

CAMERA_COMPONENT = 100


def free_udp_port():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def stdin_closed():
    r, _, _ = select.select([sys.stdin], [], [], 0)
    return bool(r) and sys.stdin.read(1) == ""


def main():
    photos = int(sys.argv[1])
    deadline = time.monotonic() + float(sys.argv[2])
    result = {"camera_list": [], "storage": None, "photos": [], "capture_infos": []}
    lock = threading.Lock()

    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    result["system_id"] = config.system_id
    mavsdk = Mavsdk(config)
    port = free_udp_port()
    mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
    print(f"PORT {port}", flush=True)

    def done(reason):
        result["reason"] = reason
        print("RESULT " + json.dumps(result), flush=True)
        mavsdk.destroy()
        sys.exit(0)

    system = None
    while system is None:
        if time.monotonic() > deadline or stdin_closed():
            done("no autopilot")
        system = mavsdk.first_autopilot(1.0)
    camera = Camera(system)

    def on_capture(info, _ud):
        p = info.position
        with lock:
            result["capture_infos"].append(
                {
                    "component_id": info.component_id,
                    "index": info.index,
                    "success": info.is_success,
                    "lat_deg": p.latitude_deg,
                    "lon_deg": p.longitude_deg,
                    "rel_alt_m": p.relative_altitude_m,
                    "time_utc_us": info.time_utc_us,
                    "file_url": info.file_url,
                    "t_mono": time.monotonic(),
                }
            )

    camera.subscribe_capture_info(on_capture)

    # The camera is listed once its information has been read.
    while not result["camera_list"]:
        if time.monotonic() > deadline or stdin_closed():
            done("no camera listed")
        result["camera_list"] = [
            {
                "component_id": c.component_id,
                "vendor_name": c.vendor_name,
                "model_name": c.model_name,
                "resolution": [c.horizontal_resolution_px, c.vertical_resolution_px],
            }
            for c in camera.camera_list().cameras
        ]
        time.sleep(0.1)
    component = result["camera_list"][0]["component_id"]

    while result["storage"] is None:
        if time.monotonic() > deadline or stdin_closed():
            done("no storage")
        try:
            s = camera.get_storage(component)
            result["storage"] = {
                "total_mib": s.total_storage_mib,
                "used_mib": s.used_storage_mib,
                "available_mib": s.available_storage_mib,
                "status": int(s.storage_status),
            }
        except CameraError as e:
            result.setdefault("storage_errors", []).append(str(e))
            time.sleep(0.2)

    for _ in range(photos):
        if time.monotonic() > deadline or stdin_closed():
            done("deadline before the photos")
        t = time.monotonic()
        try:
            camera.take_photo(component)
            outcome = "SUCCESS"
        except CameraError as e:
            outcome = str(e)
        result["photos"].append({"t_mono": t, "result": outcome})
        time.sleep(0.5)

    # Follow the stream until it has been quiet for 2 s (alfd keeps capturing in flight).
    while time.monotonic() < deadline and not stdin_closed():
        with lock:
            last = max((c["t_mono"] for c in result["capture_infos"]), default=0.0)
        if time.monotonic() - last > 2.0:
            break
        time.sleep(0.1)
    done("done")


if __name__ == "__main__":
    main()
