"""Progressive images (issue #30): zab's coder against JPEG 2000 and JPEG at 200 B … 6.4 kB.

Pictures: scikit-image's bundled ones, centre-cropped to 4:3 and scaled (Lanczos) to 320×240
— grey (camera, moon, coins, clock, and the greys of astronaut, coffee, chelsea, rocket) and
colour (astronaut, coffee, chelsea, rocket, immunohistochemistry) — and synthetic underwater
scenes (:func:`bridge.image.synthetic.seabed`: low contrast, blue-green cast, marine snow) at
160×120, 320×240 and 640×480, grey and colour.

For each budget, whole streams with their headers: zab's stream cut to the budget; JPEG 2000
encoded for the budget by OpenJPEG (glymur, a raw ``.j2k`` codestream, the compression ratio
lowered until it fits); baseline JPEG at the best quality that fits (Pillow, optimized
tables; ``—`` where none does). PSNR and SSIM (scikit-image) of the luma for colour. Then
the region of interest (a centred quarter of the picture): its PSNR without ROI coding, with
zab's (the ROI as a tile of its own between two parts of the whole picture), and coded alone
as its own picture (the most any ROI coding can give); the rest's PSNR beside. Then encode +
decode time (best of N) against OpenJPEG's (through files in a temporary folder), and how far
the stream's own distortion estimate is from the truth.

Then the image channel itself, on the virtual clock (``FastFleet``; ``--links``: only this):
seed 002's link (``deploy/missions/bluerov_images.yaml``: the polled S100 RF link, a reply
every 640 ms) and the MORPH mission (``morph.yaml`` with an image channel from cv1 to the ssv
added: TDMA, a 64-byte frame per 7.5 s cycle), refinements published at every fragment: the
time from the JPEG put on the vehicle to the first picture of ≥ 22 dB at the receiver (grey
160×120) and to the whole 1.6 kB stream, and the longest gap between two status values
meanwhile against the link's degraded-after bound.

Last, every goal of the issue in one table: what was measured, the goal, met or missed. The
issue's time limits (30 ms grey, 80 ms colour) came with OpenJPEG's 12 and 32 ms on its
machine; the same ratio to OpenJPEG as measured in this run is a row of its own, as this
machine is shared and its absolute times move with the load.

``--baseline REV`` runs the coder of a git revision beside this one (``bridge/image`` at REV,
imported under another name): its PSNR in the quality tables, its ROI gain, its time, all in
the same run.

Run: ``uv run --group bench python bench/image_bench.py [--quick] [--links] [--baseline main]``.
"""

from __future__ import annotations

import argparse
import importlib
import io
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from types import ModuleType

import glymur
import numpy as np
import skimage.data
from PIL import Image
from skimage.metrics import structural_similarity

from bridge.image.bitplanes import Planes, decode_planes
from bridge.image.codec import _read_header, decode, encode
from bridge.image.geometry import Geometry, Roi, geometry
from bridge.image.synthetic import seabed

BUDGETS = (200, 400, 800, 1600, 3200, 6400)
GREY = ("camera", "moon", "coins", "clock")
COLOUR = ("astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry")
J2K_MEAN_IN_ISSUE = {200: 20.3, 400: 24.6, 800: 27.0, 1600: 29.5, 6400: 37.1}


def baseline_codec(rev: str, folder: Path) -> ModuleType:
    """``bridge.image.codec`` as it was at git revision ``rev``, importable beside ours."""
    repo = Path(__file__).resolve().parent.parent
    archive = subprocess.run(["git", "archive", rev, "bridge/image"], cwd=repo, check=True,
                             capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    package = folder / "baseline_image"
    (folder / "bridge" / "image").rename(package)
    for source in package.glob("*.py"):
        source.write_text(source.read_text().replace("bridge.image.", "baseline_image."))
    sys.path.insert(0, str(folder))
    return importlib.import_module("baseline_image.codec")


def prepare(array: np.ndarray, width: int = 320, height: int = 240,
            grey: bool = False) -> np.ndarray:
    """Centre-crop to ``width:height`` and scale with Lanczos."""
    image = Image.fromarray(array)
    if grey:
        image = image.convert("L")
    w, h = image.size
    if w / h > width / height:
        cw = round(h * width / height)
        image = image.crop(((w - cw) // 2, 0, (w - cw) // 2 + cw, h))
    else:
        ch = round(w * height / width)
        image = image.crop((0, (h - ch) // 2, w, (h - ch) // 2 + ch))
    return np.asarray(image.resize((width, height), Image.Resampling.LANCZOS))


def luma(x: np.ndarray) -> np.ndarray:
    x = x.astype(np.float64)
    return x if x.ndim < 3 else x @ np.array([0.299, 0.587, 0.114])


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((luma(a) - luma(b)) ** 2))
    return 10 * np.log10(255 ** 2 / max(mse, 1e-6))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    return float(structural_similarity(luma(a), luma(b), data_range=255))


def ours(pixels: np.ndarray, budget: int) -> np.ndarray:
    return decode(encode(pixels, budget)).pixels


def stream_state(pixels: np.ndarray, budget: int) -> tuple[Geometry, Planes]:
    """What a decoder knows of ``pixels`` coded at ``budget`` (no ROI): the picture's
    geometry and every coefficient's known bits (for the studies)."""
    bits = bin(int.from_bytes(b"\x01" + encode(pixels, budget), "big"))[3:]
    head = _read_header(bits)
    geo = geometry(head.height, head.width, head.colour)
    return geo, decode_planes(geo, bits[head.at:], head.top)


def jpeg2000(pixels: np.ndarray, budget: int, folder: Path) -> np.ndarray | None:
    path = folder / "x.j2k"
    ratio = pixels.size / budget
    for _ in range(40):
        glymur.Jp2k(str(path), data=pixels, cratios=[ratio])
        size = path.stat().st_size
        if size <= budget:
            return np.asarray(glymur.Jp2k(str(path))[:])
        ratio *= size / budget * 1.02
    return None


def jpeg(pixels: np.ndarray, budget: int) -> np.ndarray | None:
    """Baseline JPEG at the best quality that fits (binary search), or None."""
    image = Image.fromarray(pixels)
    best = None
    lo, hi = 1, 95
    while lo <= hi:
        quality = (lo + hi) // 2
        out = io.BytesIO()
        image.save(out, format="JPEG", quality=quality, optimize=True)
        if out.tell() <= budget:
            best, lo = out.getvalue(), quality + 1
        else:
            hi = quality - 1
    return None if best is None else np.asarray(Image.open(io.BytesIO(best)))


def pictures() -> dict[str, list[np.ndarray]]:
    data = skimage.data
    grey = [prepare(getattr(data, n)()) for n in GREY]
    grey += [prepare(getattr(data, n)(), grey=True) for n in COLOUR[:4]]
    return {
        "grey 320×240 (scikit-image)": grey,
        "colour 320×240 (scikit-image, luma)": [prepare(getattr(data, n)()) for n in COLOUR],
        "underwater grey 160×120": [seabed(120, 160, s, colour=False) for s in range(3)],
        "underwater colour 320×240 (luma)": [seabed(240, 320, s) for s in range(3)],
        "underwater colour 640×480 (luma)": [seabed(480, 640, s) for s in range(2)],
    }


def quality_tables(sets: dict[str, list[np.ndarray]], folder: Path,
                   base: tuple[str, ModuleType] | None = None) -> dict[str, dict]:
    """``base``: (its name, a baseline's codec module), whose PSNR goes in a last column."""
    results: dict[str, dict] = {}
    for name, images in sets.items():
        print(f"\n{name}: mean PSNR dB / SSIM ({len(images)} pictures)")
        print(f"{'bytes':>6} | {'zab':>13} | {'JPEG 2000':>13} | {'JPEG':>15} | zab − J2K"
              + (f" | {base[0]:>8}" if base else ""))
        rows = {}
        for budget in BUDGETS:
            scores: dict[str, list[tuple[float, float]]] = {"zab": [], "j2k": [], "jpeg": []}
            before = []
            for pixels in images:
                for key, decoded in (("zab", ours(pixels, budget)),
                                     ("j2k", jpeg2000(pixels, budget, folder)),
                                     ("jpeg", jpeg(pixels, budget))):
                    if decoded is not None:
                        scores[key].append((psnr(pixels, decoded), ssim(pixels, decoded)))
                if base:
                    before.append(psnr(pixels, base[1].decode(base[1].encode(pixels,
                                                                             budget)).pixels))
            cells = []
            means = {}
            for key in ("zab", "j2k", "jpeg"):
                got = scores[key]
                if len(got) == len(images):
                    means[key] = statistics.fmean(p for p, _ in got)
                    cells.append(f"{means[key]:5.2f} / {statistics.fmean(s for _, s in got):.3f}")
                else:
                    cells.append(f"{'—':>5} ({len(got)}/{len(images)} fit)")
            delta = means["zab"] - means["j2k"] if "j2k" in means else float("nan")
            print(f"{budget:>6} | {cells[0]:>13} | {cells[1]:>13} | {cells[2]:>15} | "
                  f"{delta:+9.2f}" + (f" | {statistics.fmean(before):8.2f}" if base else ""))
            if base:
                means["base"] = statistics.fmean(before)
            rows[budget] = means
        results[name] = rows
    return results


def roi_table(name: str, images: list[np.ndarray],
              base: tuple[str, ModuleType] | None = None) -> dict[int, dict[str, float]]:
    print(f"\nROI: a centred quarter of {name}, mean PSNR dB inside (outside)")
    print(f"{'bytes':>6} | {'no ROI':>13} | {'zab ROI':>13} | {'ROI alone':>9} | gain"
          + (f"; {base[0]}'s gain" if base else ""))
    inside = (slice(60, 180), slice(80, 240))
    outside = np.ones((240, 320), dtype=bool)
    outside[inside] = False
    roi = Roi.from_fractions(0.25, 0.25, 0.75, 0.75)
    assert roi.box(240, 320) == inside
    out = {}
    for budget in (400, 800, 1600, 3200):
        cols: dict[str, tuple[float, float]] = {}
        for key, region in (("none", None), ("zab", roi)):
            ins, outs = [], []
            for pixels in images:
                decoded = decode(encode(pixels, budget, region)).pixels
                ins.append(psnr(pixels[inside], decoded[inside]))
                outs.append(psnr(pixels[outside], decoded[outside]))
            cols[key] = (statistics.fmean(ins), statistics.fmean(outs))
        alone = statistics.fmean(psnr(p[inside], ours(np.ascontiguousarray(p[inside]), budget))
                                 for p in images)
        none = cols["none"][0]
        then = ""
        if base:
            codec, roi_then = base[1], base[1].Roi.from_fractions(0.25, 0.25, 0.75, 0.75)
            then = "; {:+.2f}".format(statistics.fmean(
                psnr(p[inside], codec.decode(codec.encode(p, budget, roi_then)).pixels[inside])
                - psnr(p[inside], codec.decode(codec.encode(p, budget)).pixels[inside])
                for p in images))
        print(f"{budget:>6} | " + " | ".join(f"{cols[k][0]:5.2f} ({cols[k][1]:5.2f})"
                                             for k in ("none", "zab"))
              + f" | {alone:9.2f} | {cols['zab'][0] - none:+.2f}"
              + f"  (most: {alone - none:+.2f}){then}")
        out[budget] = {"none": none, "zab": cols["zab"][0], "alone": alone,
                       "rest": cols["zab"][1], "rest_none": cols["none"][1]}
    return out


def best_ms(fn: Callable[[], object], repeat: int) -> float:
    """The least CPU time of ``repeat`` calls (CPU, not wall: the machine is shared)."""
    return best_ms_each([fn], repeat)[0]


def best_ms_each(fns: list[Callable[[], object]], repeat: int) -> list[float]:
    """:func:`best_ms` of each of ``fns``, their calls taken in turn (so that a burst of load
    on the shared machine slows them alike, not one of them)."""
    best = [float("inf")] * len(fns)
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            start = time.process_time()
            fn()
            best[i] = min(best[i], time.process_time() - start)
    return [b * 1000 for b in best]


def timing_table(grey: np.ndarray, colour: np.ndarray, folder: Path, repeat: int,
                 base: tuple[str, ModuleType] | None = None
                 ) -> dict[str, dict[int, dict[str, float]]]:
    print(f"\nencode + decode, CPU ms (best of {repeat}), 320×240; OpenJPEG through files")
    print(f"{'bytes':>6} | {'zab grey':>8} | {'J2K grey':>8} | {'ratio':>5} | "
          f"{'zab colour':>10} | {'J2K colour':>10} | {'ratio':>5}"
          + (f" | {base[0]} grey, colour" if base else ""))
    path = folder / "t.j2k"
    out: dict[str, dict[int, dict[str, float]]] = {"grey": {}, "colour": {}}
    for budget in BUDGETS:
        cells: list[float] = []
        before: list[float] = []
        for key, pixels in (("grey", grey), ("colour", colour)):
            stream = encode(pixels, budget)
            runs: list[Callable[[], object]] = [
                lambda p=pixels, s=stream, b=budget: (encode(p, b), decode(s))]
            if base:
                codec, then = base[1], base[1].encode(pixels, budget)
                runs.append(lambda p=pixels, s=then, b=budget, c=codec: (c.encode(p, b),
                                                                          c.decode(s)))
            ms, *baseline = best_ms_each(runs, repeat)  # (the baseline's in turn with ours)
            ratio = pixels.size / budget

            def j2k(p: np.ndarray = pixels, r: float = ratio) -> None:
                glymur.Jp2k(str(path), data=p, cratios=[r])
                glymur.Jp2k(str(path))[:]

            cells += [ms, best_ms(j2k, repeat)]
            out[key][budget] = {"zab": ms, "j2k": cells[-1]}
            if baseline:
                before.append(baseline[0])
                out[key][budget]["base"] = before[-1]
        print(f"{budget:>6} | {cells[0]:8.1f} | {cells[1]:8.1f} | {cells[0] / cells[1]:5.2f} | "
              f"{cells[2]:10.1f} | {cells[3]:10.1f} | {cells[2] / cells[3]:5.2f}"
              + (f" | {before[0]:5.1f}, {before[1]:5.1f}" if base else ""))
    return out


def estimate_table(images: list[np.ndarray]) -> None:
    print("\nthe stream's own distortion estimate − the truth, PSNR dB (grey 320×240)")
    print(f"{'bytes':>6} | {'mean':>6} | {'worst':>6}")
    streams = [encode(p, BUDGETS[-1]) for p in images]
    for budget in BUDGETS:
        errors = []
        for pixels, stream in zip(images, streams, strict=True):
            decoded = decode(stream[:budget])
            errors.append(decoded.psnr_estimate - psnr(pixels, decoded.pixels))
        print(f"{budget:>6} | {statistics.fmean(errors):+6.2f} | "
              f"{max(errors, key=abs):+6.2f}")


def link_run(text: str, camera: str, receiver: str, in_key: str, out_key: str,
             status: tuple[str, str, dict], pixels: np.ndarray, seed: int) -> dict[str, float]:
    """One picture across a mission on the virtual clock: when it became recognisable, when
    it was whole, and the longest status gap meanwhile."""
    from bridge.core.link import LinkThresholds
    from bridge.core.loaded import parse_mission
    from bridge.image.formats import write_image
    from bridge.runtime.virtual_fleet import FastFleet

    loaded = parse_mission(text)
    fleet = FastFleet(loaded, seed=seed)
    start = 30.0
    status_in, status_key, status_value = status
    fleet.put(camera, status_in, status_value, at=1.0)
    fleet.put(camera, in_key, write_image(pixels, "jpeg", quality=95), encoding="image/jpeg",
              at=start)
    fleet.run_until(start + 1200.0)
    first = whole = None
    for t, publish in fleet.published(receiver, out_key):
        shown = np.asarray(Image.open(io.BytesIO(publish.value)))
        if first is None and psnr(pixels, shown) >= 22.0:
            first = t - start
        if Image.open(io.BytesIO(publish.value)).text.get("zab:final") == "true":
            whole = t - start
            break
    end = start + (whole or 1200.0)
    times = [t for t, _ in fleet.published(receiver, status_key) if start - 5 <= t <= end + 5]
    gap = max((b - a for a, b in pairwise(times)), default=float("inf"))
    return {"first": first if first is not None else float("nan"),
            "whole": whole if whole is not None else float("nan"), "status_gap": gap,
            "bound": LinkThresholds.for_mission(loaded.mission).degraded_after_s}


ROV_STATUS = {"st": 1, "ready": True, "eoid": False, "loc": False, "hold_heading": False,
              "armed": True, "nav_mode": "manual", "x": 1.0, "y": 2.0, "z": 3.0, "roll": 0.0,
              "pitch": 0.0, "yaw": 90.0}
MORPH_STATUS = {"battery": 80, "mode": "survey", "leak": False}
MORPH_IMAGES = """
images:
  - name: camera
    from: cv1
    to: ssv
    in: cv1/camera
    out: cv1/camera
    width: 160
    height: 120
    budget_bytes: 1600
"""


def link_table() -> list[tuple[str, str, str, bool | None]]:
    """The runs across missions; returns their goal rows (seed 002's link: a picture of
    ≥ 22 dB within 5 s, the 1.6 kB within 30 s; the status inside its bound on both)."""
    repo = Path(__file__).resolve().parent.parent / "deploy" / "missions"
    bluerov = (repo / "bluerov_images.yaml").read_text().replace(
        "publish_interval_s: 1.0", "publish_interval_s: 0.0")
    morph = (repo / "morph.yaml").read_text() + MORPH_IMAGES
    tests = [prepare(skimage.data.camera(), 160, 120), seabed(120, 160, 1, colour=False)]
    rows: list[tuple[str, str, str, bool | None]] = []
    print("\nlinks (virtual clock): one grey 160×120 JPEG put on the vehicle, s after the put")
    print(f"{'mission':>22} | {'picture':>8} | {'≥ 22 dB':>7} | {'1.6 kB':>7} | "
          f"{'status gap':>10} | bound")
    for name, text, args in (
            ("bluerov_images (S100)", bluerov,
             ("rov", "operator", "rov/camera", "rov/camera",
             ("rov/status", "rov/status", ROV_STATUS))),
            ("morph + camera", morph, ("cv1", "ssv", "cv1/camera", "cv1/camera",
                                       ("status", "cv1/status", MORPH_STATUS)))):
        for label, pixels in zip(("camera", "seabed"), tests, strict=True):
            got = link_run(text, *args, pixels=pixels, seed=1)
            print(f"{name:>22} | {label:>8} | {got['first']:7.1f} | {got['whole']:7.1f} | "
                  f"{got['status_gap']:10.2f} | {got['bound']:g} s")
            seed002 = name.startswith("bluerov")
            for what, value, limit in (("≥ 22 dB", got["first"], 5.0),
                                       ("1.6 kB", got["whole"], 30.0)):
                rows.append((f"{name}, {label}: {what} after", f"{value:.1f} s",
                             f"≤ {limit:g} s" if seed002 else "(figure)",
                             value <= limit if seed002 else None))
            rows.append((f"{name}, {label}: longest status gap", f"{got['status_gap']:.2f} s",
                         f"≤ {got['bound']:g} s", got["status_gap"] <= got["bound"]))
    return rows


def goals(quality: dict[str, dict], rois: dict[str, dict[int, dict[str, float]]],
          times: dict[str, dict[int, dict[str, float]]],
          links: list[tuple[str, str, str, bool | None]]) -> None:
    """Each goal of the issue: what was measured, the goal, met or missed. Times also as
    ratios to OpenJPEG's (and the baseline's, with ``--baseline``) measured in this run."""
    grey = quality["grey 320×240 (scikit-image)"]
    colour = quality["colour 320×240 (scikit-image, luma)"]
    rows: list[tuple[str, str, str, bool | None]] = []
    for name, table in quality.items():
        short = [b for b in BUDGETS if table[b].get("zab", 0) < table[b].get("j2k", 0)]
        least = min(BUDGETS, key=lambda b: table[b]["zab"] - table[b].get("j2k", 0))
        rows.append((f"{name}: PSNR vs JPEG 2000, every budget",
                     f"{table[least]['zab'] - table[least].get('j2k', 0):+.2f} dB at {least} B"
                     + (f" (short at {short})" if short else ""), "≥ +0 dB", not short))
    rows.append(("grey 320×240 at 200 B", f"{grey[200]['zab']:.2f} dB", "≥ 23.5 dB",
                 grey[200]["zab"] >= 23.5))
    rows.append(("colour 320×240 luma at 800 B", f"{colour[800]['zab']:.2f} dB", "≥ 26.5 dB",
                 colour[800]["zab"] >= 26.5))
    for name, roi in rois.items():
        for budget, least_db in ((800, 3.0), (1600, 5.0)):
            gain = roi[budget]["zab"] - roi[budget]["none"]
            most = roi[budget]["alone"] - roi[budget]["none"]
            rows.append((f"ROI gain, {name}, {budget} B", f"{gain:+.2f} dB (most {most:+.2f})",
                         f"≥ +{least_db:g} dB", gain >= least_db))
            rows.append((f"  the rest's PSNR meanwhile (without ROI coding "
                         f"{roi[budget]['rest_none']:.2f})", f"{roi[budget]['rest']:.2f} dB",
                         "(figure)", None))
    for key, limit, openjpeg in (("grey", 30.0, 12.0), ("colour", 80.0, 32.0)):
        worst = max(times[key], key=lambda b: times[key][b]["zab"])
        at = times[key][worst]
        every = times[key].values()
        base = ""
        if "base" in at:
            summed = sum(t["zab"] for t in every) / sum(t["base"] for t in every)
            base = f" (all budgets: ×{summed:.2f} the baseline's time)"
        rows.append((f"encode + decode {key} 320×240, worst budget ({worst} B)",
                     f"{at['zab']:.1f} ms{base}", f"≤ {limit:g} ms", at["zab"] <= limit))
        # the issue's limits came with OpenJPEG's times on its machine: the same ratio here
        # (OpenJPEG's time hardly depends on the budget: its median is the steadier measure)
        ratio = at["zab"] / statistics.median(t["j2k"] for t in every)
        rows.append(("  the same as a ratio to OpenJPEG's median time in this run",
                     f"×{ratio:.2f}", f"≤ ×{limit / openjpeg:.2f}", ratio <= limit / openjpeg))
    rows += links
    print("\ngoals (issue #30)")
    width = max(len(r[0]) for r in rows)
    measured = max(len(r[1]) for r in rows)
    print(f"{'goal':<{width}} | {'measured':<{measured}} | {'wanted':<9} | result")
    for what, got, want, ok in rows:
        result = "—" if ok is None else "met" if ok else "MISSED"
        print(f"{what:<{width}} | {got:<{measured}} | {want:<9} | {result}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer timing repeats")
    parser.add_argument("--links", action="store_true", help="only the runs across missions")
    parser.add_argument("--baseline", metavar="REV",
                        help="also run bridge/image of this git revision, side by side")
    args = parser.parse_args()
    if args.links:
        link_table()
        return
    sets = pictures()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        base = (args.baseline, baseline_codec(args.baseline, folder / "baseline")) \
            if args.baseline else None
        quality = quality_tables(sets, folder, base)
        grey_set = sets["grey 320×240 (scikit-image)"]
        print("\n(the issue's JPEG 2000 on its own grey pictures: "
              + ", ".join(f"{b} B {v}" for b, v in J2K_MEAN_IN_ISSUE.items()) + " dB)")
        rois = {"grey 320×240": roi_table("grey 320×240 (scikit-image)", grey_set, base),
                "underwater grey 320×240": roi_table(
                    "underwater grey 320×240", [seabed(240, 320, s, colour=False)
                                                for s in range(4)], base)}
        times = timing_table(grey_set[0], sets["colour 320×240 (scikit-image, luma)"][0],
                             folder, 5 if args.quick else 30, base)
    estimate_table(grey_set)
    goals(quality, rois, times, link_table())


if __name__ == "__main__":
    main()
