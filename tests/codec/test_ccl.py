"""CCL encodings (seed 003): 24-bit lat/lon, sliding-scale depth, altitude, layouts."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bridge.codec import Layout
from bridge.errors import DecodeError


def one(codec: str, **params: float) -> Layout:
    return Layout.from_fields([{"field": "v", "codec": codec, "params": params}])


@pytest.mark.parametrize(("codec", "limit"), [("ccl.latitude", 90), ("ccl.longitude", 180)])
def test_latlon(codec: str, limit: int) -> None:
    layout = one(codec)
    assert layout.bits == 24
    step = limit / (2**23 - 1)
    assert layout.fields[0].describe().startswith(f"{codec} 24 bit")
    for x in (-limit, limit, 0.0):
        assert layout.unpack(layout.pack({"v": x}))["v"] == x
    assert layout.pack({"v": limit}) == 2**23 - 1
    assert layout.pack({"v": -limit}) == 2**24 - (2**23 - 1)  # two's complement
    assert layout.pack({"v": step}) == 1
    assert layout.pack({"v": -step}) == 2**24 - 1
    with pytest.raises(DecodeError):
        layout.unpack(2**23)  # -2**23 is not used
    # resolution: a few metres at most (1° of latitude ~ 111 km)
    assert step * 111_320 < 2.5


@settings(max_examples=200, deadline=None)
@given(st.floats(-180, 180))
def test_longitude_round_trip(x: float) -> None:
    layout = one("ccl.longitude")
    assert abs(layout.unpack(layout.pack({"v": x}))["v"] - x) <= 180 / (2**23 - 1) / 2 + 1e-9


def test_depth_sliding_scale() -> None:
    layout = one("ccl.depth")
    codec = layout.fields[0]
    assert codec.bits == 13  # 1000 + 500 + 1600 + 5001 = 8101 levels
    rt = lambda x: layout.unpack(layout.pack({"v": x}))["v"]  # noqa: E731
    # steps of each band
    assert [rt(x) for x in (0, 0.1, 12.34, 99.9)] == [0.0, 0.1, 12.3, 99.9]
    assert [rt(x) for x in (100.0, 100.2, 150.29, 199.8)] == [100.0, 100.2, 150.2, 199.8]
    assert [rt(x) for x in (200.0, 200.5, 512.3, 999.5)] == [200.0, 200.5, 512.5, 999.5]
    assert [rt(x) for x in (1000, 1001, 4321.4, 6000)] == [1000.0, 1001.0, 4321.0, 6000.0]
    # band edges are continuous: 99.97 rounds up into the next band's first code
    assert rt(99.97) == 100.0
    assert layout.pack({"v": 100.0}) == 1000
    assert layout.pack({"v": 200.0}) == 1500
    assert layout.pack({"v": 1000.0}) == 3100
    assert layout.pack({"v": 6000.0}) == 8100
    with pytest.raises(DecodeError):
        layout.unpack(8101)
    layout.pack({"v": 7000})
    assert layout.clamped == {"v": 1}
    assert one("ccl.depth", max=1000).bits == 12


@settings(max_examples=300, deadline=None)
@given(st.floats(0, 6000))
def test_depth_error_within_half_step(x: float) -> None:
    layout = one("ccl.depth")
    step = 0.1 if x < 100 else 0.2 if x < 200 else 0.5 if x < 1000 else 1.0
    got = layout.unpack(layout.pack({"v": x}))["v"]
    assert abs(got - x) <= step / 2 + 1e-9
    assert layout.unpack_reference(layout.pack_reference({"v": x}))["v"] == got


def test_altitude() -> None:
    layout = one("ccl.altitude")
    assert layout.bits == 13
    assert layout.unpack(layout.pack({"v": 655}))["v"] == 655.0
    assert layout.unpack(layout.pack({"v": 12.34}))["v"] == 12.3


def test_bathymetry_layout_loads_by_name() -> None:
    layout = Layout.from_fields([{"field": "bathy", "layout": "ccl/bathymetry"}])
    assert [f.path for f in layout.fields] == [
        "bathy.depth",
        "bathy.altitude",
        "bathy.latitude",
        "bathy.longitude",
    ]
    assert layout.bits == 3 * (13 + 13 + 24 + 24)
    assert layout.nbytes <= 31  # fits a CCL message after its type byte
    value = {
        "bathy": {
            "depth": [5.0, 150.2, 2500.0],
            "altitude": [1.5, 20.0, 655.0],
            "latitude": [41.5, 41.5, 41.5],
            "longitude": [-70.6, -70.6, -70.6],
        }
    }
    out = layout.decode(layout.encode(value))["bathy"]
    assert out["depth"] == [5.0, 150.2, 2500.0]
    assert out["altitude"] == [1.5, 20.0, 655.0]
    assert all(abs(a - 41.5) < 1e-5 for a in out["latitude"])
    assert Layout.load("ccl/bathymetry").description.startswith("CCL bathymetry")


def test_redirect_and_state_layouts() -> None:
    redirect = Layout.load("ccl/redirect")
    assert redirect.nbytes <= 30  # Table 2 fits a 32-byte message
    state = Layout.load("ccl/state")
    assert state.bits == 122
