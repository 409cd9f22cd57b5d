"""Image channels and surfacing, on the virtual clock: while the operator is reachable over
IP the camera's picture reaches it whole (relayed as it came on the output key) and not as
acoustic refinements; a picture already crossing goes on to its end; after the dive,
pictures cross the water again."""

from __future__ import annotations

from bridge.core.loaded import parse_mission
from bridge.core.surfacing import Relay
from bridge.runtime.virtual_fleet import FastFleet
from tests.conftest import MISSIONS
from tests.runtime.test_images_fleet import JPEG, pictures

SAME_KEY = (MISSIONS / "bluerov_images.yaml").read_text().replace(
    "mission: bluerov_images", "mission: bluerov_images\nsurfacing: {republish: true}")
MISSION = SAME_KEY.replace(  # (the camera's own key: relayed to rov/camera)
    "    in: rov/camera\n", "    in: camera\n")


def relays(fleet: FastFleet, node: str) -> list[Relay]:
    return [o.output for o in fleet.outputs if o.node == node and isinstance(o.output, Relay)]


def test_a_surfaced_operator_gets_the_picture_whole_and_no_coarser_copies() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    [relay] = relays(fleet, "rov")
    assert (relay.key, relay.data, relay.encoding) == ("rov/camera", JPEG, "image/jpeg")
    assert pictures(fleet) == []  # nothing crossed the water to be shown
    assert fleet.cores["rov"].images is not None
    camera = next(iter(fleet.cores["rov"].images.inputs.values()))
    assert camera.current is None and camera.last is not None  # kept for a request

    fleet.ip_link("operator", "rov", False)  # the dive: a request sends it acoustically
    fleet.put("operator", "camera/control", {"request": "now"}, at=41.0)
    fleet.run_until(80.0)
    got = pictures(fleet)
    assert got and got[-1][1]["zab:final"] == "true"


def test_a_picture_crossing_when_the_operator_surfaces_is_shown_to_its_end() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(8.0)
    assert len(pictures(fleet)) >= 2
    fleet.ip_link("operator", "rov", True)
    fleet.run_until(40.0)
    got = pictures(fleet)
    assert got[-1][1]["zab:final"] == "true"  # (it came before the IP path: never put there)
    assert relays(fleet, "rov") == []


def test_a_picture_begun_by_a_camera_that_has_not_noticed_the_surfacing_is_not_shown() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.cores["operator"].ip_reachable("rov", True, 0.5)  # (the ROV's bridge: not yet)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(40.0)
    assert pictures(fleet) == []
    surfacing = fleet.cores["operator"].surfacing
    assert surfacing is not None and surfacing.duplicates > 0


def test_a_picture_asked_for_while_surfaced_comes_over_ip_where_it_can() -> None:
    fleet = FastFleet(parse_mission(MISSION, "surf.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.put("operator", "camera/control", {"request": "now"}, at=10.0)
    fleet.run_until(40.0)
    assert [r.key for r in relays(fleet, "rov")] == ["rov/camera", "rov/camera"]  # put, asked
    assert pictures(fleet) == []


def test_where_the_output_key_is_the_input_key_a_picture_asked_for_crosses_and_shows() -> None:
    """The operator's applications saw the put itself over IP; asked for again, the picture
    can only cross the water, and the operator shows it."""
    fleet = FastFleet(parse_mission(SAME_KEY, "same.yaml"), seed=1)
    fleet.ip_link("operator", "rov", True)
    fleet.put("rov", "rov/camera", JPEG, encoding="image/jpeg", at=1.0)
    fleet.run_until(8.0)
    assert relays(fleet, "rov") == [] and pictures(fleet) == []  # (seen as put: not sent)
    fleet.put("operator", "camera/control", {"request": "now"}, at=10.0)
    fleet.run_until(50.0)
    got = pictures(fleet)
    assert got and got[-1][1]["zab:final"] == "true"
