"""Outputs written as one unit (staged_outputs) and output paths checked before any work."""

import os
import stat

import pytest

from needlekit.io.files import output_path_problem, staged_outputs, write_json, write_text


def _tree(root):
    """Every path under root with its kind, bytes and mode: to show nothing changed."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            st = os.lstat(p)
            data = open(p, "rb").read() if stat.S_ISREG(st.st_mode) else None
            out[os.path.relpath(p, root)] = (stat.S_IFMT(st.st_mode), data, st.st_mode & 0o7777)
    return out


def test_files_appear_only_when_the_block_ends(tmp_path):
    with staged_outputs():
        write_text(tmp_path / "a.txt", "a")
        write_json(tmp_path / "sub" / "b.json", {"b": 1})
        assert not (tmp_path / "a.txt").exists() and not (tmp_path / "sub" / "b.json").exists()
    assert (tmp_path / "a.txt").read_text() == "a"
    assert (tmp_path / "sub" / "b.json").read_text() == '{\n  "b": 1\n}\n'
    assert sorted(_tree(tmp_path)) == ["a.txt", "sub", "sub/b.json"]  # no temporary files


def test_an_error_in_the_block_leaves_every_file_as_it_was(tmp_path):
    write_text(tmp_path / "sweep.json", "old sweep")
    before = _tree(tmp_path)
    with pytest.raises(RuntimeError, match="report failed"), staged_outputs():
        write_text(tmp_path / "sweep.json", "new sweep")
        write_text(tmp_path / "new" / "deeper" / "plan.json", "new plan")
        raise RuntimeError("report failed")
    assert _tree(tmp_path) == before  # old content, no temporary files, no new folders


def test_a_move_that_fails_puts_back_the_files_already_moved(tmp_path):
    write_text(tmp_path / "a.txt", "old a")
    with pytest.raises(IsADirectoryError), staged_outputs():
        write_text(tmp_path / "a.txt", "new a")
        write_text(tmp_path / "b.txt", "new b")
        (tmp_path / "b.txt").mkdir()  # b cannot be moved into place: a was, and goes back
    assert (tmp_path / "a.txt").read_text() == "old a"
    assert sorted(_tree(tmp_path)) == ["a.txt", "b.txt"] and (tmp_path / "b.txt").is_dir()


def test_blocks_nest_and_the_outer_one_decides(tmp_path):
    with pytest.raises(KeyboardInterrupt), staged_outputs():
        with staged_outputs():
            write_text(tmp_path / "inner.txt", "inner")
        assert not (tmp_path / "inner.txt").exists()
        raise KeyboardInterrupt
    assert _tree(tmp_path) == {}


def test_a_file_written_twice_keeps_the_last_version(tmp_path):
    with staged_outputs():
        write_text(tmp_path / "a.txt", "first")
        write_text(tmp_path / "a.txt", "second")
    assert _tree(tmp_path) == {"a.txt": (stat.S_IFREG, b"second", _tree(tmp_path)["a.txt"][2])}


@pytest.fixture
def places(tmp_path):
    """A writable folder, a read-only one (refused even for root), a file, a read-only
    file; modes restored afterwards."""
    ro = tmp_path / "ro"
    ro.mkdir()
    (tmp_path / "dir").mkdir()
    (tmp_path / "file.txt").write_text("x")
    (tmp_path / "locked.json").write_text("old")
    ro.chmod(0o555)
    (tmp_path / "locked.json").chmod(0o444)
    yield tmp_path
    ro.chmod(0o755)
    (tmp_path / "locked.json").chmod(0o644)


@pytest.mark.parametrize(
    ("rel", "folder", "reason"),
    [
        ("dir/new.json", False, None),
        ("dir/a/b/c/new.json", False, None),
        ("file.txt", False, None),
        ("dir", True, None),
        ("dir/new-folder", True, None),
        ("ro/new.json", False, "folder {root}/ro is read-only"),
        ("ro/a/b/new.json", False, "folder {root}/ro is read-only"),
        ("file.txt/new.json", False, "cannot be created: {root}/file.txt is not a folder"),
        ("dir", False, "is a folder, expected a file"),
        ("locked.json", False, "is read-only"),
        ("ro", True, "is read-only"),
        ("file.txt", True, "is a file, expected a folder"),
        ("file.txt/sub", True, "cannot be created: {root}/file.txt is not a folder"),
    ],
)
def test_output_path_problem(places, rel, folder, reason):
    before = _tree(places)
    got = output_path_problem(places / rel, folder=folder)
    assert got == (None if reason is None else reason.format(root=places))
    assert _tree(places) == before  # the write probe leaves nothing behind


def test_output_path_problem_refuses_devices():
    assert output_path_problem(os.devnull) == "is not a regular file (a device, pipe or socket)"


# ---------------------------------------------------------------------------------------
# what a failing verdict and an interrupted run leave (the README's contract)


def test_a_failing_verdict_replaces_no_file_that_exists_and_writes_beside_it(tmp_path):
    write_text(tmp_path / "plan.json", "solved plan")
    with staged_outputs() as outputs:
        write_text(tmp_path / "plan.json", "infeasible plan")
        write_text(tmp_path / "report.html", "new page")  # no file there: written in place
        outputs.keep_earlier()
    assert (tmp_path / "plan.json").read_text() == "solved plan"
    assert (tmp_path / "plan.failed.json").read_text() == "infeasible plan"
    assert (tmp_path / "report.html").read_text() == "new page"
    assert outputs.diverted == [(tmp_path / "plan.json", tmp_path / "plan.failed.json")]
    assert sorted(_tree(tmp_path)) == ["plan.failed.json", "plan.json", "report.html"]


def test_an_interrupted_block_puts_only_its_partial_record_and_new_files_in_place(tmp_path):
    from needlekit.errors import Interrupted

    write_text(tmp_path / "sweep.json", "complete sweep")
    with pytest.raises(Interrupted), staged_outputs():
        write_text(tmp_path / "sweep.json", "a sweep half done")  # never over the complete one
        write_text(tmp_path / "case1" / "execute.json", "a finished case")  # new: kept
        write_json(tmp_path / "sweep.partial.json", {"partial": True}, partial=True)
        raise Interrupted("stopped")
    assert (tmp_path / "sweep.json").read_text() == "complete sweep"
    assert (tmp_path / "case1" / "execute.json").read_text() == "a finished case"
    assert sorted(_tree(tmp_path)) == ["case1", "case1/execute.json", "sweep.json",
                                       "sweep.partial.json"]  # fmt: skip


def test_a_finished_run_removes_the_partial_record_it_carried_on_from(tmp_path):
    from needlekit.io.partial import write_partial

    write_partial(tmp_path / "sweep.json", {"done": [1]}, key_file=tmp_path / "key")
    assert (tmp_path / "sweep.partial.json").exists() and not (tmp_path / "sweep.json").exists()
    with staged_outputs() as outputs:  # a failing verdict keeps it (nothing earlier changes)
        write_text(tmp_path / "sweep.json", "complete, but no plan found")
        outputs.keep_earlier()
    assert (tmp_path / "sweep.partial.json").exists()
    with staged_outputs():
        write_text(tmp_path / "sweep.json", "complete")
    assert not (tmp_path / "sweep.partial.json").exists()
    write_partial(tmp_path / "sweep.json", {"done": [1]}, key_file=tmp_path / "key")
    write_text(tmp_path / "sweep.json", "complete, outside a block")  # the same rule
    assert not (tmp_path / "sweep.partial.json").exists()


def test_a_run_that_finishes_with_a_failing_verdict_leaves_no_partial_record_of_its_own(tmp_path):
    # a study writes its partial record between cases, then its complete record: exit 1
    # (its goal does not hold) keeps earlier outputs, but the partial record this very run
    # wrote is stale, and an earlier run's stays
    from needlekit.io.partial import write_partial

    key = tmp_path / "key"
    with staged_outputs() as outputs:
        write_partial(tmp_path / "lungs.json", {"cases": [1]}, key_file=key)
        write_partial(tmp_path / "lungs.json", {"cases": [1, 2]}, key_file=key)
        write_text(tmp_path / "lungs.json", "complete, the goal not held")
        outputs.keep_earlier()
    assert sorted(_tree(tmp_path)) == ["key", "lungs.json"]
    write_partial(tmp_path / "other.json", {"cases": [1]}, key_file=key)  # an earlier run's
    write_text(tmp_path / "other.json", "complete")  # (outside a block: removes it)
    write_partial(tmp_path / "other.json", {"cases": [1]}, key_file=key)
    earlier = (tmp_path / "other.partial.json").read_text()
    with staged_outputs() as outputs:
        write_partial(tmp_path / "other.json", {"cases": [1, 2]}, key_file=key)
        write_text(tmp_path / "other.json", "complete again, the goal not held")
        outputs.keep_earlier()
    assert (tmp_path / "other.partial.json").read_text() == earlier
    assert (tmp_path / "other.failed.json").exists()
