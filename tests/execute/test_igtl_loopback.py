"""The live link of `needlekit execute --igtl`, in a loopback: a pyigtl
client connects to the command, counts and decodes every message (TRANSFORM, POLYDATA,
STRING), and checks names, timestamps and coordinates (RAS mm) against the run's own
record; with --tip-from-igtl the client plays the tracker, sending the tip back as
NeedleToTracker, and the closed loop runs on those poses."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

pyigtl = pytest.importorskip("pyigtl", reason="pyigtl: pip install -e .[igtl]")

from needlekit.cli import main  # noqa: E402
from needlekit.execute.feedback import PlanReference  # noqa: E402
from needlekit.scenario.results import read_plan_json  # noqa: E402

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"
NAMES = ("NeedleTip", "NeedleTipTrue", "NeedlePlan", "NeedleState")


class _PolyData(pyigtl.PolyDataMessage):
    """POLYDATA read as OpenIGTLink's specification lays it out (pyigtl 0.3 sends it but
    does not read it): ten counts, then the points as big-endian float32."""

    def _unpack_content(self, content):
        counts = struct.unpack("> 10I", content[:40])
        n = counts[0]
        self.points = np.frombuffer(content[40 : 40 + 12 * n], dtype=">f4").reshape(n, 3)
        self.lines = np.frombuffer(content[40 + 12 * n : 40 + 12 * n + counts[4]], dtype=">u4")


class _Every(dict):
    """pyigtl keeps the newest message per name; this keeps every one, in order."""

    def __init__(self, log):
        super().__init__()
        self.log = log

    def __setitem__(self, key, value):
        self.log.append(value)
        super().__setitem__(key, value)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("igtl") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


def _run(toy_plan, out, extra, echo=False, pace=("--igtl-realtime", "10", "--speed-mm-s", "10")):
    pyigtl.messages.message_type_to_class_constructor.setdefault("POLYDATA", _PolyData)
    port = _free_port()
    log: list = []
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port, start_now=False)
    client.incoming_messages = _Every(log)
    client.start()
    stop = threading.Event()

    def tracker():  # sends each true tip back, as a tracker behind PLUS would
        sent = 0
        while not stop.is_set():
            tips = [m for m in log[sent:] if m.device_name == "NeedleTipTrue"]
            sent = len(log)
            for m in tips:
                client.send_message(pyigtl.TransformMessage(
                    m.matrix, timestamp=m.timestamp, device_name="NeedleToTracker"), wait=False)  # fmt: skip
            time.sleep(0.002)

    if echo:
        threading.Thread(target=tracker, daemon=True).start()
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(out),
                     "--igtl", str(port), "--igtl-wait-s", "20", *pace, "--replan-delay-ms", "5",
                     *extra])  # fmt: skip
        time.sleep(0.2)  # the last messages in flight
    finally:
        stop.set()
        client.stop()
    return code, log


def test_every_instant_streams_the_tip_the_plan_and_the_state(toy_plan, tmp_path, capsys):
    code, log = _run(toy_plan, tmp_path, [])
    assert code == 0
    counts = Counter(m.device_name for m in log)
    n = counts["NeedleTip"]
    assert set(counts) == set(NAMES) and all(counts[name] == n for name in NAMES)
    sent = int(capsys.readouterr().out.split("OpenIGTLink: ")[1].split()[0])
    assert sent == 4 * n  # nothing lost on the way
    record = json.loads((tmp_path / "execute.json").read_text())["trials"][0]["closed_loop"]
    # one instant per sensor period (40 Hz) of the insertion, and one at its end
    duration = record["inserted_mm"] / 10.0
    assert abs(n - (duration * 40 + 1)) <= 2
    # the four messages of an instant share its timestamp; instants a sensor period (25 ms)
    # apart, the last one where the insertion stopped (32.32 fixed point on the wire)
    stamps = np.array([m.timestamp for m in log]).reshape(n, 4)
    assert np.all(stamps == stamps[:, :1])
    gaps = np.diff(stamps[:, 0])
    assert np.allclose(gaps[:-1], 0.025, atol=1e-6) and 0.0 < gaps[-1] <= 0.025 + 1e-6
    by = {name: [m for m in log if m.device_name == name] for name in NAMES}
    # coordinates: RAS mm, as the record has them (float32 on the wire)
    end = np.asarray(by["NeedleTipTrue"][-1].matrix)
    assert np.allclose(end[:3, 3], record["points_mm"][-1], atol=1e-3)
    plan, goal, _ = read_plan_json(toy_plan)
    first = by["NeedlePlan"][0]
    ref = PlanReference.of_plan(plan, goal)
    assert np.allclose(first.points, ref.points_mm, atol=1e-3)
    assert list(first.lines) == [len(ref.points_mm), *range(len(ref.points_mm))]
    assert by["NeedleState"][-1].string.endswith("done")
    assert f"replans={record['replans']}" in by["NeedleState"][-1].string


def test_the_tip_can_come_from_a_tracker_over_the_link(toy_plan, tmp_path, capsys):
    # twice real time: the tracker's round trip (a few ms) stays well under the sensor period
    code, _ = _run(toy_plan, tmp_path, ["--tip-from-igtl", "NeedleToTracker"], echo=True,
                   pace=("--igtl-realtime", "2", "--speed-mm-s", "20"))  # fmt: skip
    out = capsys.readouterr().out
    received = int(out.split("messages sent, ")[1].split()[0])
    assert code == 0 and received >= 5
    record = json.loads((tmp_path / "execute.json").read_text())["trials"][0]["closed_loop"]
    # every pose the tracker sent, and nothing else, judged by the sensor guard
    assert record["samples"] + sum(record["rejected"].values()) == received, record["rejected"]
    assert not record["rejected"], (record["rejected"], record["faults"])
    assert record["final_error_mm"] < 1.0


def test_the_link_flags_are_checked_before_any_work(toy_plan, tmp_path, capsys):
    for flags, words in (
        (["--igtl", "70000"], "--igtl"),
        (["--igtl", "18944", "--trials", "3"], "--replay-trial K"),
        (["--tip-from-igtl", "NeedleToTracker"], "--tip-from-igtl"),
        (["--igtl", "18944", "--trials", "1", "--workers", "2"], "--igtl"),
    ):
        assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--out", str(tmp_path / "x"), *flags]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err
    assert not (tmp_path / "x").exists()


def test_a_client_that_leaves_ends_the_stream_in_one_line_and_the_run_goes_on(
    toy_plan, tmp_path, capsys, caplog
):
    port = _free_port()
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port, start_now=True)
    threading.Timer(0.3, client.stop).start()  # Slicer closed a moment after connecting
    code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(tmp_path),
                 "--igtl", str(port), "--igtl-realtime", "10", "--speed-mm-s", "10",
                 "--replan-delay-ms", "5"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0 and "Traceback" not in err
    said = [r.getMessage() for r in caplog.records if "OpenIGTLink" in r.getMessage()]
    assert len(said) == 1 and "the connection failed" in said[0]
    record = json.loads((tmp_path / "execute.json").read_text())["trials"][0]["closed_loop"]
    assert record["final_error_mm"] < 1.0  # the insertion ran to its end


def test_the_link_connects_to_a_server_when_given_a_host(toy_plan, tmp_path, capsys):
    import signal

    port = _free_port()
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    server = pyigtl.OpenIGTLinkServer(port=port, local_server=True)
    log: list = []
    server.incoming_messages = _Every(log)
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(tmp_path),
                     "--igtl", f"127.0.0.1:{port}", "--igtl-realtime", "10", "--speed-mm-s",
                     "10", "--replan-delay-ms", "5"])  # fmt: skip
        time.sleep(0.2)
    finally:
        server.stop()
        for s, h in before.items():
            signal.signal(s, h)
    sent = int(capsys.readouterr().out.split("OpenIGTLink: ")[1].split()[0])
    assert code == 0 and sent > 0
    assert Counter(m.device_name for m in log)["NeedleTip"] == sent // 4
