"""Masks from NIfTI and NRRD: affines against nibabel, LPS->RAS, round trips, bad files."""

import gzip

import nibabel as nib
import nrrd
import numpy as np
import pytest
from nibabel.affines import apply_affine
from scipy.spatial.transform import Rotation

from needlekit.errors import InvalidInputError
from needlekit.io.volumes import Mask, read_mask, write_mask_nifti, write_mask_nrrd


def _mask(shape=(6, 7, 8), seed=0):
    rng = np.random.default_rng(seed)
    m = rng.random(shape) < 0.2
    m[1, 2, 3] = True
    return m


def _affine(kind):
    a = np.eye(4)
    if kind == "diag":
        a[:3, :3] = np.diag([0.5508, 0.5508, 0.7])
        a[:3, 3] = [-143.5, 37.8, 1033.2]
    elif kind == "lps_flipped":  # as the Med-RAD livers: ('L', 'P', 'S')
        a[:3, :3] = np.diag([-0.78125, -0.78125, 5.0])
        a[:3, 3] = [224.8, 200.0, -375.0]
    elif kind == "oblique":
        rot = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
        perm = np.eye(3)[[1, 2, 0]] * np.array([-1.0, 1.0, -1.0])[:, None]
        a[:3, :3] = rot @ perm @ np.diag([0.6, 0.9, 1.3])
        a[:3, 3] = [10.0, -20.0, 30.0]
    elif kind == "sheared":
        a[:3, :3] = [[1.0, 0.3, 0.0], [0.0, 1.0, 0.0], [0.0, 0.1, 2.0]]
        a[:3, 3] = [5.0, 0.0, 1.0]
    return a


def _world_points(mask: Mask):
    return apply_affine(mask.affine, np.argwhere(mask.data))


# ----------------------------------------------------------------------------------------
# NIfTI


@pytest.mark.parametrize("kind", ["diag", "lps_flipped", "oblique", "sheared"])
@pytest.mark.parametrize("suffix", [".nii", ".nii.gz"])
def test_nifti_round_trip_matches_nibabel(tmp_path, kind, suffix):
    m, a = _mask(), _affine(kind)
    path = write_mask_nifti(tmp_path / f"mask{suffix}", m, a)
    got = read_mask(path)
    img = nib.load(path)
    assert got.data.dtype == bool and np.array_equal(got.data, m)
    assert np.allclose(got.affine, a, atol=1e-5 * np.abs(a).max())  # float32 storage
    assert np.array_equal(got.affine, img.affine)
    assert got.axcodes() == nib.aff2axcodes(a)
    assert np.allclose(_world_points(got), apply_affine(a, np.argwhere(m)), atol=1e-3)
    assert got.path == path
    assert not got.data.flags.writeable and not got.affine.flags.writeable
    if kind == "sheared":
        assert int(img.header["qform_code"]) == 0 and int(img.header["sform_code"]) == 2


@pytest.mark.parametrize(
    ("values", "dtype"),
    [((0, 1), np.int16), ((0, 255), np.uint8), ((0.0, 1.0), np.float32), ((0, -3), np.int32)],
)
def test_nifti_masks_of_any_numeric_type(tmp_path, values, dtype):
    m = _mask()
    data = np.where(m, values[1], values[0]).astype(dtype)
    path = tmp_path / "m.nii.gz"
    nib.save(nib.Nifti1Image(data, _affine("diag")), path)
    assert np.array_equal(read_mask(path).data, m)


def test_trailing_singleton_axis_is_dropped(tmp_path):
    m = _mask()
    path = tmp_path / "m4.nii"
    nib.save(nib.Nifti1Image(m[..., None].astype(np.uint8), np.eye(4)), path)
    assert read_mask(path).shape == m.shape


def test_mask_object_round_trips_through_both_writers(tmp_path):
    first = read_mask(write_mask_nifti(tmp_path / "a.nii", _mask(), _affine("oblique")))
    second = read_mask(write_mask_nrrd(tmp_path / "b.nrrd", first))
    assert np.array_equal(first.data, second.data)
    assert np.allclose(first.affine, second.affine, atol=1e-12)


# ----------------------------------------------------------------------------------------
# NRRD


def _nrrd_header(affine_ras, space):
    flips = {"left-posterior-superior": [-1, -1, 1], "LPS": [-1, -1, 1]}.get(space, None)
    if flips is None:
        flips = [-1, 1, 1] if space.startswith("left-anterior") else [1, 1, 1]
    a = np.diag([*flips, 1.0]) @ affine_ras
    return {"space": space, "space directions": a[:3, :3].T, "space origin": a[:3, 3]}


@pytest.mark.parametrize("kind", ["diag", "lps_flipped", "oblique"])
@pytest.mark.parametrize(
    "space", ["left-posterior-superior", "right-anterior-superior", "left-anterior-superior"]
)
def test_nrrd_world_matches_the_same_mask_as_nifti(tmp_path, kind, space):
    m, a = _mask(), _affine(kind)
    nifti = read_mask(write_mask_nifti(tmp_path / "m.nii.gz", m, a))
    path = tmp_path / "m.nrrd"
    nrrd.write(str(path), m.astype(np.uint8), _nrrd_header(a, space))
    got = read_mask(path)
    assert np.array_equal(got.data, m)
    assert np.allclose(got.affine, a, atol=1e-12)
    assert np.allclose(got.affine, nifti.affine, atol=1e-5)
    assert got.axcodes() == nifti.axcodes()
    assert np.allclose(_world_points(got), _world_points(nifti), atol=1e-3)


def test_lps_header_holds_negated_x_and_y(tmp_path):
    a = _affine("diag")
    path = write_mask_nrrd(tmp_path / "m.nrrd", _mask(), a)
    _, header = nrrd.read(str(path))
    assert header["space"] == "left-posterior-superior"
    assert np.allclose(header["space directions"], np.diag([-0.5508, -0.5508, 0.7]))
    assert np.allclose(header["space origin"], [143.5, -37.8, 1033.2])


def test_detached_nhdr_header(tmp_path):
    m, a = _mask(), _affine("oblique")
    path = tmp_path / "m.nhdr"
    nrrd.write(str(path), m.astype(np.uint8), _nrrd_header(a, "LPS"))
    assert (tmp_path / "m.raw.gz").exists() or len(list(tmp_path.iterdir())) == 2
    got = read_mask(path)
    assert np.array_equal(got.data, m) and np.allclose(got.affine, a)


# ----------------------------------------------------------------------------------------
# bad files


def _nifti_with_sform(path, data, sform):
    img = nib.Nifti1Image(data, None)
    img.set_sform(sform, code=2)
    nib.save(img, path)
    return path


def _bad_files(tmp_path):
    m = _mask().astype(np.uint8)
    eye = np.eye(4)
    three = m.copy()
    three[0, 0, 0] = 2
    nan = m.astype(np.float32)
    nan[0, 0, 0] = np.nan
    coplanar = np.eye(4)
    coplanar[:3, 2] = [1.0, 1.0, 0.0]
    cases = {
        "missing": (tmp_path / "missing.nii.gz", "file not found"),
        "ext": (tmp_path / "mask.mha", "unsupported extension"),
        "two_d": (tmp_path / "flat.nii", "3-D volume, got shape \\(6, 7\\)"),
        "four_d": (tmp_path / "four.nii", "3-D volume, got shape \\(6, 7, 8, 2\\)"),
        "three_values": (tmp_path / "labels.nii", r"more than 2 distinct values \(0, 1, 2\)"),
        "no_zero": (tmp_path / "nozero.nii", "values 1 and 2, expected 0"),
        "nan": (tmp_path / "nan.nii", "NaN"),
        "singular": (tmp_path / "singular.nii", "singular or degenerate"),
        "coplanar": (tmp_path / "coplanar.nii", "singular or degenerate"),
        "empty": (tmp_path / "empty.nii.gz", "empty mask"),
        "corrupt": (tmp_path / "corrupt.nii.gz", "not a readable NIfTI file"),
        "no_orientation": (tmp_path / "analyze.nii", "neither sform nor qform"),
        "nrrd_no_space": (tmp_path / "nospace.nrrd", "no 'space' field"),
        "nrrd_scanner": (tmp_path / "scanner.nrrd", "unsupported NRRD space 'scanner-xyz'"),
        "nrrd_no_origin": (tmp_path / "noorigin.nrrd", "no 'space origin' field"),
        "nrrd_corrupt": (tmp_path / "corrupt.nrrd", "not a readable NRRD file"),
    }
    cases["ext"][0].write_bytes(b"")
    nib.save(nib.Nifti1Image(m[:, :, 0], eye), cases["two_d"][0])
    nib.save(nib.Nifti1Image(np.stack([m, m], axis=-1), eye), cases["four_d"][0])
    nib.save(nib.Nifti1Image(three, eye), cases["three_values"][0])
    nib.save(nib.Nifti1Image(m + 1, eye), cases["no_zero"][0])
    nib.save(nib.Nifti1Image(nan, eye), cases["nan"][0])
    _nifti_with_sform(cases["singular"][0], m, np.diag([1.0, 0.0, 1.0, 1.0]))
    _nifti_with_sform(cases["coplanar"][0], m, coplanar)
    nib.save(nib.Nifti1Image(np.zeros_like(m), eye), cases["empty"][0])
    cases["corrupt"][0].write_bytes(gzip.compress(b"not a nifti file at all" * 20))
    bare = nib.Nifti1Image(m, eye)
    bare.set_sform(None, code=0)
    bare.set_qform(None, code=0)
    nib.save(bare, cases["no_orientation"][0])
    nrrd.write(str(cases["nrrd_no_space"][0]), m)
    hdr = {"space": "scanner-xyz", "space directions": np.eye(3), "space origin": np.zeros(3)}
    nrrd.write(str(cases["nrrd_scanner"][0]), m, hdr)
    nrrd.write(
        str(cases["nrrd_no_origin"][0]), m, {"space": "LPS", "space directions": eye[:3, :3]}
    )
    cases["nrrd_corrupt"][0].write_bytes(b"NRRD0005\ntype: nonsense\n\n")
    return cases


BAD = [
    "missing", "ext", "two_d", "four_d", "three_values", "no_zero", "nan", "singular",
    "coplanar", "empty", "corrupt", "no_orientation", "nrrd_no_space", "nrrd_scanner", "nrrd_no_origin",
    "nrrd_corrupt",
]  # fmt: skip


@pytest.mark.parametrize("case", BAD)
def test_bad_files_raise_naming_the_file(tmp_path, case):
    path, match = _bad_files(tmp_path)[case]
    with pytest.raises(InvalidInputError, match=match) as info:
        read_mask(path)
    assert info.value.field == str(path)


def test_empty_mask_allowed_on_request(tmp_path):
    path = write_mask_nifti(tmp_path / "e.nii", np.zeros((3, 3, 3), bool), np.eye(4))
    assert not read_mask(path, allow_empty=True).data.any()


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda d: write_mask_nifti(d / "m.nrrd", _mask(), np.eye(4)), r"\.nii"),
        (lambda d: write_mask_nrrd(d / "m.nii", _mask(), np.eye(4)), r"\.nrrd"),
        (lambda d: write_mask_nifti(d / "m.nii", _mask()), "needs its voxel->RAS affine"),
        (lambda d: write_mask_nifti(d / "m.nii", _mask()[0], np.eye(4)), "3-D"),
        (lambda d: write_mask_nifti(d / "m.nii", _mask() + 1.5, np.eye(4)), "expected 0"),
        (lambda d: write_mask_nrrd(d / "m.nrrd", _mask(), np.eye(4), space="scanner-xyz"), "space"),
        (lambda d: write_mask_nrrd(d / "m.nrrd", _mask(), np.zeros((4, 4))), "affine"),
    ],
)
def test_writers_reject_bad_input_and_leave_no_file(tmp_path, call, match):
    with pytest.raises(InvalidInputError, match=match):
        call(tmp_path)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------
# real data


@pytest.mark.realdata
def test_medrad_liver_mask_is_lps_oriented(medrad_dir):
    path = medrad_dir / "Liver" / "Patient1" / "hepaticArtery.nii.gz"
    mask = read_mask(path)
    img = nib.load(path)
    assert mask.axcodes() == ("L", "P", "S")
    assert np.array_equal(mask.affine, img.affine)
    assert np.array_equal(mask.data, np.asanyarray(img.dataobj) != 0)
    assert mask.data.any()


@pytest.mark.realdata
@pytest.mark.slow
def test_medrad_lung_pleural_boundary(medrad_dir):
    path = medrad_dir / "Lungs" / "TumorTargetEnvironments" / "Patient1" / "pleuralBoundary.nii.gz"
    mask = read_mask(path)
    assert mask.shape == (497, 331, 512)
    assert mask.axcodes() == ("R", "A", "S")
    assert np.allclose(mask.spacing_mm, [0.5508, 0.5508, 0.7], atol=1e-4)


@pytest.mark.parametrize("dtype", ["int16", ">i2", "uint8", "int32", "int64"])
@pytest.mark.parametrize("order", ["F", "C", "strided"])
@pytest.mark.parametrize("values", [(0, 1), (0, -3), (7, 0), (0, 0), (5, 5), (1, 2), (0, 1, 2)])
def test_one_pass_binarise_agrees_with_numpy(dtype, order, values):
    """The reader's kernel (io._binarise) against numpy's passes: the same mask, C-ordered,
    the same verdict on the two-value rule, the same count, whatever the layout."""
    from needlekit.io._binarise import binarise

    rng = np.random.default_rng(len(values) * 31 + sum(values))
    shape = (37, 70, 41)  # tiles of 32 do not divide it
    data = np.asarray(rng.choice(values, size=shape), dtype=dtype)
    if order == "F":
        data = np.asfortranarray(data)
    elif order == "strided":
        data = np.asfortranarray(np.repeat(data, 2, axis=1))[:, ::2]
    mask, ok, count = binarise(data)
    assert mask.flags.c_contiguous and mask.dtype == bool
    distinct = set(np.unique(data).tolist())
    binary = len(distinct) == 1 or (len(distinct) == 2 and 0 in distinct)
    assert ok == binary
    if binary:
        np.testing.assert_array_equal(mask, data != 0)
        assert count == int((data != 0).sum())
    assert binarise(data.astype(np.float32)) is None  # floats stay with numpy


def test_non_binary_file_is_refused_with_its_values(tmp_path):
    data = np.zeros((5, 6, 7), np.int16)
    data[1, 2, 3], data[2, 2, 2] = 1, 4
    p = tmp_path / "three.nii.gz"
    nib.save(nib.Nifti1Image(data, np.eye(4)), p)
    with pytest.raises(
        InvalidInputError, match=r"three.nii.gz.*more than 2 distinct values \(0, 1, 4\)"
    ):
        read_mask(p)


@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.float32, ">i2"])
@pytest.mark.parametrize("nifti2", [False, True])
def test_voxels_read_as_a_view_equal_nibabels(tmp_path, dtype, nifti2):
    """Unscaled single-file NIfTI: the voxels are a view of the inflated bytes (no copy),
    equal to nibabel's array and affine; scaled images go through nibabel."""
    from needlekit.io.volumes import _direct_nifti

    rng = np.random.default_rng(5)
    data = rng.integers(0, 2, size=(7, 9, 11)).astype(dtype)
    affine = _affine("oblique")
    cls = nib.Nifti2Image if nifti2 else nib.Nifti1Image
    img = cls(data, affine)
    raw = img.to_bytes()
    direct = _direct_nifti(raw, nifti2)
    assert direct is not None
    np.testing.assert_array_equal(direct.dataobj, np.asanyarray(img.dataobj))
    np.testing.assert_array_equal(direct.affine, cls.from_bytes(raw).affine)
    img.header.set_slope_inter(2.0, 0.0)
    assert _direct_nifti(img.to_bytes(), nifti2) is None
    assert _direct_nifti(raw[:200], nifti2) is None  # truncated: nibabel says why


@pytest.mark.realdata
def test_medrad_voxels_as_a_view_equal_nibabels(medrad_dir):
    from isal import igzip

    from needlekit.io.volumes import _direct_nifti

    path = medrad_dir / "Lungs" / "TumorTargetEnvironments" / "Patient4" / "fissures.nii.gz"
    raw = igzip.decompress(path.read_bytes())
    direct = _direct_nifti(raw, False)
    img = nib.load(path)
    np.testing.assert_array_equal(direct.dataobj, np.asanyarray(img.dataobj))
    np.testing.assert_array_equal(direct.affine, img.affine)


@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.int32])
@pytest.mark.parametrize("nifti2", [False, True])
@pytest.mark.parametrize("extension", [False, True])
def test_streamed_gz_mask_equals_the_whole_file_read(tmp_path, dtype, nifti2, extension):
    """``.nii.gz`` masks are inflated slab by slab into the mask: the same mask, count and
    affine as reading the file whole, with header extensions and either NIfTI version."""
    from needlekit.io.volumes import _read_whole, _stream_mask_gz

    m = _mask()
    cls = nib.Nifti2Image if nifti2 else nib.Nifti1Image
    img = cls(np.where(m, 3, 0).astype(dtype), _affine("oblique"))
    if extension:
        img.header.extensions.append(nib.nifti1.Nifti1Extension("comment", b"x" * 300))
    path = tmp_path / "m.nii.gz"
    nib.save(img, path)
    streamed = _stream_mask_gz(path)
    assert streamed is not None
    whole = _read_whole(path, "nifti")
    np.testing.assert_array_equal(streamed[0], whole[0])
    assert streamed[0].flags.c_contiguous and streamed[1] == int(m.sum())
    np.testing.assert_allclose(streamed[2], whole[2], rtol=0, atol=0)
    np.testing.assert_array_equal(read_mask(path).data, m)


@pytest.mark.parametrize("chunk_planes", [1, 3, 7, 1000])
def test_binarise_stream_across_slab_boundaries(chunk_planes):
    import io

    from needlekit.io._binarise import binarise_stream

    rng = np.random.default_rng(chunk_planes)
    data = np.asfortranarray(rng.choice([0, 9], size=(13, 11, 17)).astype(np.int16))
    stream = io.BytesIO(data.tobytes(order="F"))
    got = binarise_stream(stream.readinto, np.dtype(np.int16), data.shape,
                          chunk_bytes=chunk_planes * 13 * 11 * 2)  # fmt: skip
    np.testing.assert_array_equal(got[0], data != 0)
    assert got[1] and got[2] == int((data != 0).sum())
    third = data.copy(order="F")
    third[12, 10, 16] = 5  # a third value in the last slab
    stream = io.BytesIO(third.tobytes(order="F"))
    assert binarise_stream(stream.readinto, np.dtype(np.int16), data.shape, 13 * 11 * 2) is None
    short = io.BytesIO(data.tobytes(order="F")[:-1])  # one byte missing
    assert binarise_stream(short.readinto, np.dtype(np.int16), data.shape) is None


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_masks_read_together_are_the_masks_read_one_by_one(tmp_path, monkeypatch, threads):
    import needlekit.io.volumes as prepare

    monkeypatch.setattr(prepare, "READ_THREADS", threads)
    paths = {}
    for k, shape in enumerate([(6, 7, 8), (30, 20, 10), (9, 5, 4), (12, 12, 12)]):
        data = _mask(shape, seed=k)
        paths[f"m{k}"] = write_mask_nifti(tmp_path / f"m{k}.nii.gz", data, _affine("oblique"))
    paths["empty"] = write_mask_nifti(tmp_path / "e.nii.gz", np.zeros((3, 3, 3), bool), np.eye(4))
    said = []
    got = prepare.read_masks(paths, said.append, allow_empty=("empty",))
    assert list(got) == list(paths) and said == [f"masks {k}/5" for k in range(1, 6)]
    for name, path in paths.items():
        one = read_mask(path, allow_empty=name == "empty")
        assert np.array_equal(got[name].data, one.data) and np.array_equal(got[name].affine, one.affine)
    # the first bad file in the given order is the one named, whichever finished first
    (tmp_path / "bad.nii.gz").write_bytes(b"not a mask")
    bad = {"m1": paths["m1"], "bad": tmp_path / "bad.nii.gz", "empty": paths["empty"]}
    with pytest.raises(InvalidInputError, match=r"bad\.nii\.gz"):
        prepare.read_masks(bad)
    with pytest.raises(InvalidInputError, match=r"e\.nii\.gz.*empty mask"):
        prepare.read_masks({"m1": paths["m1"], "empty": paths["empty"]})
