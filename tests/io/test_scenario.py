"""Scenario files: building scenes, frames, errors that name file and field, fuzzing."""

import copy
import json

import numpy as np
import pytest
import trimesh
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from needlekit.anatomy.primitives import Capsule, Cylinder, Ellipsoid, Sphere, Superquadric
from needlekit.anatomy.scene import Role
from needlekit.errors import InvalidInputError, NeedlekitError
from needlekit.io.scenario_schema import SCENARIO_SCHEMA
from needlekit.scenario.loading import load_scenario, parse_scenario

TOY = {
    "version": 1,
    "name": "toy lung",
    "structures": [
        {"name": "lung", "role": "allowed_region", "ellipsoid": {"semi_axes_mm": [80, 60, 100]}},
        {
            "name": "vessel",
            "role": "obstacle",
            "capsule": {"p0_mm": [-40, 10, 0], "p1_mm": [40, 10, 20], "radius_mm": 4},
        },
        {
            "name": "airway",
            "role": "obstacle",
            "cylinder": {"p0_mm": [0, -20, -90], "p1_mm": [0, -20, 90], "radius_mm": 8},
        },
        {"name": "nodule", "role": "target", "sphere": {"center_mm": [20, 30, 40], "radius_mm": 7}},
        {
            "name": "head",
            "role": "obstacle",
            "superquadric": {"semi_axes_mm": [40, 3, 3], "exponents": [8, 2, 2]},
        },
    ],
    "needle": {"diameter_mm": 1.0, "r_min_mm": 60},
    "start": {"point_mm": [0, -12, 0], "direction": [0, 1, 0.3]},
    "goal": {"point_mm": [20, 30, 40], "tolerance_mm": 0.5},
    "planner": {"name": "rcs_star", "time_limit_s": 1.0, "seed": 3},
}


def write(tmp_path, data, name="s.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return p


def test_toy_scenario_builds_the_promised_scene(tmp_path):
    sc = load_scenario(write(tmp_path, TOY))
    assert sc.scene.names == ["lung", "vessel", "airway", "nodule", "head"]
    assert sc.scene["lung"].role is Role.ALLOWED_REGION and sc.scene["nodule"].role is Role.TARGET
    rng = np.random.default_rng(0)
    p = rng.uniform(-90, 90, (200, 3))
    refs = {
        "lung": Ellipsoid([80, 60, 100]),
        "vessel": Capsule([-40, 10, 0], [40, 10, 20], 4),
        "airway": Cylinder([0, -20, -90], [0, -20, 90], 8),
        "nodule": Sphere([20, 30, 40], 7),
        "head": Superquadric([40, 3, 3], [8, 2, 2]),
    }
    got = sc.scene.signed_distance(p)
    for name, ref in refs.items():
        assert np.allclose(got[name], ref.signed_distance(p), atol=1e-9)
    assert sc.needle.r_min_mm == 60 and sc.needle.max_length_mm == 150  # default kept
    assert sc.needle.clearance_margin_mm == pytest.approx(0.5)
    z = sc.start.world_T_tip[:3, 2]
    assert np.allclose(z, np.array([0, 1, 0.3]) / np.linalg.norm([0, 1, 0.3]))
    assert np.allclose(sc.start.world_T_tip[:3, :3].T @ sc.start.world_T_tip[:3, :3], np.eye(3))
    assert np.allclose(sc.goal.point_mm, [20, 30, 40]) and sc.goal.tolerance_mm == 0.5
    assert sc.planner == {"name": "rcs_star", "time_limit_s": 1.0, "seed": 3}
    assert sc.path.name == "s.yaml"


def test_lps_frame_is_converted_to_ras(tmp_path):
    lps = copy.deepcopy(TOY)
    lps["frame"] = "LPS"
    ras_sc = parse_scenario(TOY)
    lps_sc = parse_scenario(lps)
    flip = np.array([-1.0, -1.0, 1.0])
    rng = np.random.default_rng(1)
    p = rng.uniform(-90, 90, (100, 3))
    a = ras_sc.scene.signed_distance(p)
    b = lps_sc.scene.signed_distance(p * flip)
    for name in a:
        assert np.allclose(a[name], b[name], atol=1e-9)
    assert np.allclose(lps_sc.goal.point_mm, ras_sc.goal.point_mm * flip)
    assert np.allclose(lps_sc.start.world_T_tip[:3, 2], ras_sc.start.world_T_tip[:3, 2] * flip)


def test_pose_file_and_point_file(tmp_path):
    g = np.eye(4)
    g[:3, 3] = [1, 2, 3]
    np.savetxt(tmp_path / "start.txt", g)
    (tmp_path / "target.txt").write_text("20\n30\n40\n")
    data = copy.deepcopy(TOY)
    data["start"] = {"pose_file": "start.txt"}
    data["goal"] = {"point_file": "target.txt"}
    sc = load_scenario(write(tmp_path, data))
    assert np.allclose(sc.start.world_T_tip, g) and sc.start.name == "start.txt"
    assert np.allclose(sc.goal.point_mm, [20, 30, 40])


def test_mask_and_mesh_sources(tmp_path):
    from needlekit.io.volumes import write_mask_nifti

    m = np.zeros((30, 30, 30), bool)
    m[10:20, 10:20, 10:20] = True
    write_mask_nifti(tmp_path / "cube.nii.gz", m, np.diag([1.0, 1.0, 1.0, 1.0]))
    trimesh.creation.icosphere(subdivisions=3, radius=10.0).export(tmp_path / "ball.stl")
    data = {
        "version": 1,
        "structures": [
            {"name": "cube", "role": "obstacle", "mask": {"path": "cube.nii.gz"}},
            {"name": "ball", "role": "target", "mesh": {"path": "ball.stl", "voxel_size_mm": 1.0}},
        ],
    }
    sc = load_scenario(write(tmp_path, data))
    cube = sc.scene["cube"].field
    # the mask's surface is the boundary of the voxels' boxes: x = 9.5 .. 19.5 mm
    assert abs(float(cube.signed_distance([25.0, 14.5, 14.5])) - 5.5) <= cube.error_bound_mm
    ball = sc.scene["ball"].field
    assert abs(float(ball.signed_distance([0.0, 0.0, 15.0])) - 5.0) <= ball.error_bound_mm + 0.2
    # without a voxel size the mesh gets its largest side / 256, within 0.25-2 mm
    del data["structures"][1]["mesh"]["voxel_size_mm"]
    ball = load_scenario(write(tmp_path, data)).scene["ball"].field
    assert np.allclose(ball.spacing_mm, 0.25)  # a 20 mm ball: 20 / 256 < 0.25
    assert abs(float(ball.signed_distance([0.0, 0.0, 15.0])) - 5.0) <= ball.error_bound_mm + 0.2


@pytest.mark.parametrize(
    ("mutate", "field", "message"),
    [
        (lambda d: d.update(version=2), "version", "expected 1"),
        (lambda d: d.update(colour="red"), "(top level)", "unknown field 'colour'"),
        (
            lambda d: d["structures"][1]["capsule"].update(radius_mm=-1),
            "structures[1].capsule.radius_mm",
            "0",
        ),
        (
            lambda d: d["structures"][1]["capsule"].update(radius_mm="big"),
            "structures[1].capsule.radius_mm",
            "expected number",
        ),
        (lambda d: d["structures"][0].update(role="wall"), "structures[0].role", "expected one of"),
        (lambda d: d["structures"][0].pop("name"), "structures[0]", "'name' is missing"),
        (
            lambda d: d["structures"][2].update(sphere={"center_mm": [0, 0, 0], "radius_mm": 1}),
            "structures[2]",
            "exactly one source",
        ),
        (lambda d: d["structures"][2].pop("cylinder"), "structures[2]", "exactly one source"),
        (lambda d: d["structures"][3].update(name="lung"), "structures[3].name", "duplicate"),
        (
            lambda d: d["structures"][3]["sphere"].update(center_mm=[1, 2]),
            "structures[3].sphere.center_mm",
            "3 to 3 items",
        ),
        (lambda d: d["start"].update(pose=np.eye(4).tolist()), "start", "exactly one"),
        (
            lambda d: d.update(start={"pose": np.diag([2.0, 1.0, 1.0, 1.0]).tolist()}),
            "start.pose",
            "rotation",
        ),
        (lambda d: d.update(start={"case_start": 1}), "start.case_start", "base"),
        (lambda d: d.update(goal={"point_file": "nope.txt"}), "goal.point_file", "not found"),
        (
            lambda d: d.update(
                structures=[{"name": "m", "role": "obstacle", "mask": {"path": "none.nii.gz"}}]
            ),
            "structures[0].mask.path",
            "not found",
        ),
        (
            lambda d: d.update(base={"phantom": {"name": "kidney"}}),
            "base.phantom.name",
            "expected one of",
        ),
        (lambda d: d["needle"].update(r_min_mm=0), "needle.r_min_mm", "0"),
        # planner names are open (plug-ins register more): the registry refuses unknown
        # ones when a command runs; the schema refuses what cannot be a name
        (lambda d: d["planner"].update(name=5), "planner.name", "expected string"),
    ],
)
def test_errors_name_file_field_and_expectation(tmp_path, mutate, field, message):
    data = copy.deepcopy(TOY)
    mutate(data)
    path = write(tmp_path, json.loads(json.dumps(data)), "case.yaml")
    with pytest.raises(InvalidInputError) as info:
        load_scenario(path)
    text = str(info.value)
    assert text.startswith(f"case.yaml: {field}:"), text
    assert message in text, text
    assert "\n" not in text


def test_file_level_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        load_scenario(tmp_path / "missing.yaml")
    with pytest.raises(InvalidInputError, match=r"invalid YAML at line 3, column 1"):
        load_scenario(write(tmp_path, "version: 1\nstructures: [unclosed\n"))
    with pytest.raises(InvalidInputError, match="mapping at the top level"):
        load_scenario(write(tmp_path, "- 1\n- 2\n"))
    with pytest.raises(InvalidInputError, match="'version' is missing"):
        load_scenario(write(tmp_path, "name: x\n"))
    with pytest.raises(InvalidInputError, match="no structures"):
        load_scenario(write(tmp_path, "version: 1\n"))


def test_schema_is_valid_json_schema():
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(SCENARIO_SCHEMA)
    assert set(SCENARIO_SCHEMA["properties"]) >= {
        "base",
        "structures",
        "needle",
        "start",
        "goal",
        "planner",
    }


# ---------------------------------------------------------------------------------------
# fuzzing: malformed documents give needlekit's own errors, nothing else

_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
)  # fmt: skip
_value = st.recursive(
    _leaf,
    lambda c: st.one_of(
        st.lists(c, max_size=5), st.dictionaries(st.text(max_size=10), c, max_size=5)
    ),
    max_leaves=12,
)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, (*prefix, i))


def _mutate(doc, path, action, value, key):
    doc = copy.deepcopy(doc)
    if not path:
        return value if action == "replace" else doc
    parent = doc
    for part in path[:-1]:
        parent = parent[part]
    last = path[-1]
    if action == "replace":
        parent[last] = value
    elif action == "delete":
        del parent[last]
    elif isinstance(parent, dict):
        parent[key] = value
    return doc


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    index=st.integers(min_value=0, max_value=10**6),
    action=st.sampled_from(["replace", "delete", "add"]),
    value=_value,
    key=st.text(max_size=10),
)
def test_fuzzed_documents_raise_only_needlekit_errors(index, action, value, key):
    paths = list(_paths(TOY))
    doc = _mutate(TOY, paths[index % len(paths)], action, value, key)
    try:
        parse_scenario(doc, source="fuzz.yaml")
    except NeedlekitError as exc:
        assert str(exc).startswith("fuzz.yaml: "), str(exc)
        assert "\n" not in str(exc)


@settings(max_examples=150, deadline=None)
@given(doc=_value)
def test_random_documents_raise_only_needlekit_errors(doc):
    try:
        parse_scenario(doc, source="random.yaml")
    except NeedlekitError as exc:
        assert str(exc).startswith("random.yaml: "), str(exc)


@settings(
    max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(text=st.text(max_size=200))
def test_random_text_files_raise_only_needlekit_errors(tmp_path, text):
    p = tmp_path / "t.yaml"
    p.write_text(text)
    try:
        load_scenario(p)
    except NeedlekitError:
        pass
