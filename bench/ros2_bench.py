"""ROS 2 messages from plain data to CDR and back: bridge.ros2.messages against rosbags alone.

Run: ``uv run --group bench python bench/ros2_bench.py [--repeat 5]``.
For messages the bridge publishes or reads in bulk (a receiver's picture as a
``CompressedImage``, a camera's JPEG put over IP while surfaced, a raw 1080p ``Image``, an
``Odometry``), prints the best time of ``--repeat`` runs of :func:`encode_cdr` (build the
message from plain data, then serialise) and :func:`decode_cdr`, beside rosbags serialising
and deserialising the message already built, measured side by side in the same run: the
ratio is what the plain-data layer adds. (Arrays went through a Python list one value at a
time until stop 50: a 500 kB JPEG took ~0.5 s to encode, a 1080p frame ~6.5 s.)
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from typing import Any

from bridge.ros2.messages import decode_cdr, encode_cdr, typestore

DISTRO = "jazzy"
CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "CompressedImage, 20 kB PNG": ("sensor_msgs/msg/CompressedImage", {
        "format": "mono8; png compressed mono8", "data": os.urandom(20_000)}),
    "CompressedImage, 500 kB JPEG": ("sensor_msgs/msg/CompressedImage", {
        "format": "rgb8; jpeg compressed bgr8", "data": os.urandom(500_000)}),
    "Image, 1080p rgb8": ("sensor_msgs/msg/Image", {
        "height": 1080, "width": 1920, "encoding": "rgb8", "step": 5760,
        "data": os.urandom(1920 * 1080 * 3)}),
    "Odometry": ("nav_msgs/msg/Odometry", {
        "header": {"frame_id": "map"}, "pose": {"pose": {"position": {"x": 1.0, "y": 2.0}},
                                                "covariance": [0.1] * 36}}),
}


def best_ms(fn: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    repeat = parser.parse_args().repeat
    store = typestore(DISTRO)
    print(f"{'message':>30} | {'encode ms':>9} | {'rosbags':>8} | {'ratio':>5} | "
          f"{'decode ms':>9} | {'rosbags':>8} | {'ratio':>5}")
    for name, (msgtype, tree) in CASES.items():
        data = encode_cdr(DISTRO, msgtype, tree)
        built = store.deserialize_cdr(data, msgtype)
        enc = best_ms(lambda t=msgtype, v=tree: encode_cdr(DISTRO, t, v), repeat)
        ser = best_ms(lambda t=msgtype, m=built: store.serialize_cdr(m, t), repeat)
        dec = best_ms(lambda t=msgtype, d=data: decode_cdr(DISTRO, t, d), repeat)
        des = best_ms(lambda t=msgtype, d=data: store.deserialize_cdr(d, t), repeat)
        print(f"{name:>30} | {enc:9.3f} | {ser:8.3f} | {enc / ser:5.1f} | "
              f"{dec:9.3f} | {des:8.3f} | {dec / des:5.1f}")


if __name__ == "__main__":
    main()
