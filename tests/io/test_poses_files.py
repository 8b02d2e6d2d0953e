"""Pose/point text files and atomic writes."""

import json

import numpy as np
import pytest

from needlekit.errors import InvalidInputError, OutputError
from needlekit.geometry.se3 import se3_exp
from needlekit.io.files import atomic_write, write_json
from needlekit.io.poses import read_point_txt, read_pose_txt, write_pose_txt


def test_pose_round_trip(tmp_path):
    g = se3_exp([10.0, -5.0, 1200.0, 0.3, -1.2, 2.0])
    path = write_pose_txt(tmp_path / "start.txt", g)
    assert np.allclose(read_pose_txt(path), g, atol=1e-15)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("1 0 0\n0 1 0\n0 0 1\n", "16 numbers"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n1 2 3 4\n", "16 numbers"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 x\n", "numbers"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 nan\n0 0 0 1\n", r"entry \[2, 3\]: expected a number in"),
        ("1 0 0 1e308\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"entry \[0, 3\]: expected a number in"),
        ("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "proper rotation"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 1\n", "last row"),
    ],
)
def test_bad_pose_files_name_the_file(tmp_path, text, match):
    path = tmp_path / "bad_start.txt"
    path.write_text(text)
    with pytest.raises(InvalidInputError, match=r"bad_start\.txt") as info:
        read_pose_txt(path)
    assert info.match(match)


def test_point_file(tmp_path):
    p = tmp_path / "target.txt"
    p.write_text("6.4e+01\n2.0e+02\n1.2e+03\n")
    assert np.allclose(read_point_txt(p), [64.0, 200.0, 1200.0])
    p.write_text("1 2\n")
    with pytest.raises(InvalidInputError, match="3 numbers"):
        read_point_txt(p)
    with pytest.raises(InvalidInputError, match="not found"):
        read_point_txt(tmp_path / "missing.txt")


def test_atomic_write_leaves_old_content_on_failure(tmp_path):
    dest = tmp_path / "out.json"
    write_json(dest, {"a": 1})

    def boom(path):
        path.write_text("half")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        atomic_write(dest, boom)
    assert json.loads(dest.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]
    with pytest.raises(OutputError, match=r"^out.json: x: computed value is nan"):
        write_json(dest, {"x": float("nan")})
    assert json.loads(dest.read_text()) == {"a": 1}
