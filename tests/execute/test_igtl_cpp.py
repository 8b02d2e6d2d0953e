"""The live link against peers nobody here wrote: the OpenIGTLink C++ library's own example
programs (Debian's ``openigtlink-examples`` sources built against ``libopenigtlink-dev`` by
``make igtl-examples``). ``ReceiveClient`` reads what ``execute --igtl`` sends and decodes
every TRANSFORM and STRING; ``TrackerServer``, taken as the tip tracker, sends transforms
that have nothing to do with the needle (a circle under its own frame) and never reads:
needlekit says so in one line, holds the needle, aborts after the hold timeout, crosses
nothing, and its own stream does not stall. Loopback only."""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("pyigtl", reason="pyigtl: pip install -e .[igtl]")

from needlekit.cli import main

ROOT = Path(__file__).resolve().parents[2]
TOY = ROOT / "examples" / "toy.yaml"
BUILT = Path(os.environ.get("NEEDLEKIT_IGTL_EXAMPLES", ROOT / ".cache" / "igtl-examples"))
RECEIVE_CLIENT = BUILT / "Receiver" / "ReceiveClient"
TRACKER_SERVER = BUILT / "Tracker" / "TrackerServer"


def _need(program: Path) -> None:
    if not os.access(program, os.X_OK):
        pytest.skip(f"{program.name} not built at {program.parent}: `make igtl-examples` builds "
                    "it (Debian's libopenigtlink-dev and openigtlink-examples, cmake)")  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("igtl-cpp") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


def _receive_client(port: int, out: Path, holder: dict, stop: threading.Event) -> None:
    """Start ReceiveClient once needlekit listens (it says "Cannot connect" and exits
    before: start it again)."""
    while not stop.is_set():
        with out.open("w") as f:
            proc = subprocess.Popen([str(RECEIVE_CLIENT), "127.0.0.1", str(port)], stdout=f,
                                    stderr=subprocess.STDOUT)  # fmt: skip
            try:
                proc.wait(0.2)
            except subprocess.TimeoutExpired:
                holder["proc"] = proc
                return
        if "Cannot connect" not in out.read_text(errors="replace"):
            holder["proc"] = proc
            return
        time.sleep(0.05)


def test_the_libraries_receive_client_decodes_every_transform_and_string(toy_plan, tmp_path, capsys):
    _need(RECEIVE_CLIENT)
    port = _free_port()
    out = tmp_path / "client.txt"
    holder: dict = {}
    stop = threading.Event()
    threading.Thread(target=_receive_client, args=(port, out, holder, stop), daemon=True).start()
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(tmp_path),
                     "--igtl", str(port), "--igtl-wait-s", "20", "--igtl-realtime", "4",
                     "--speed-mm-s", "10", "--replan-delay-ms", "5"])  # fmt: skip
    finally:
        stop.set()
        proc = holder.get("proc")
        try:  # it exits when the other end closes
            client_code = None if proc is None else proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            client_code = "killed"
    assert code == 0 and client_code == 0  # it exits when needlekit closes the link
    sent = int(capsys.readouterr().out.split("OpenIGTLink: ")[1].split()[0])
    instants = sent // 4
    text = out.read_text(errors="replace")
    # every instant: two TRANSFORMs, a POLYDATA (a type it does not know: it skips the
    # body) and a STRING, each TRANSFORM and STRING decoded with its CRC checked
    assert text.count("Receiving TRANSFORM data type.") == 2 * instants
    assert text.count("Receiving STRING data type.") == instants
    assert text.count("Receiving : POLYDATA") == instants
    assert text.count("=============") == 2 * 2 * instants  # every matrix printed: CRC held
    states = re.findall(r"String: (t=[^\n]*)", text)
    assert len(states) == instants and states[0].startswith("t=0.005 s inserted=0.05 mm")  # after the first step
    assert states[-1].endswith("done")


def test_the_libraries_tracker_server_as_the_tracker_is_refused_and_holds(toy_plan, tmp_path, capsys):
    _need(TRACKER_SERVER)
    port = _free_port()
    server = subprocess.Popen([str(TRACKER_SERVER), str(port), "40"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        time.sleep(0.3)  # its socket listening
        code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(tmp_path),
                     "--igtl", f"127.0.0.1:{port}", "--igtl-wait-s", "20", "--igtl-realtime", "2",
                     "--speed-mm-s", "10", "--tip-from-igtl", "Tracker", "--hold-timeout-s", "1",
                     "--replan-delay-ms", "5"])  # fmt: skip
    finally:
        server.terminate()
        server.wait(5)
    captured = capsys.readouterr()
    record = json.loads((tmp_path / "execute.json").read_text())["trials"][0]["closed_loop"]
    # its transforms are not the needle's: every one refused, the needle held, then aborted
    received = int(captured.out.split("messages sent, ")[1].split()[0])
    assert received >= 5 and record["samples"] == 0
    assert sum(record["rejected"].values()) == received
    said = [line for line in captured.err.splitlines() if "the needle is held" in line]
    assert said, captured.err
    # its first transform lies 50 mm off the needle; it stamps none (each time 0 s): the
    # rest have a timestamp that does not advance
    assert record["rejected"].get("jump", 0) >= 1
    assert set(record["rejected"]) <= {"jump", "frozen"}
    assert record["aborted"] and code == 1 and not record["violated"]
    # its server never reads: needlekit's stream did not stall the insertion or the link
    assert "connection failed" not in captured.err
