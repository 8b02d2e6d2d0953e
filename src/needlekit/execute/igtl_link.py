"""A live link to 3D Slicer over OpenIGTLink (``needlekit execute --igtl``), through pyigtl.

While a closed-loop insertion runs, every sensor period (40 Hz by default) of simulated
time, paced to the wall clock (``realtime``: 1 is real time), the link sends

- ``NeedleTip`` (TRANSFORM): the estimated tip pose, the one the navigation knows;
- ``NeedleTipTrue`` (TRANSFORM): the simulated true tip;
- ``NeedlePlan`` (POLYDATA): the plan being followed, one polyline of its points;
- ``NeedleState`` (STRING): ``t=... s inserted=... mm goal=... mm replans=N inserting``
  (``done`` at the end).

Coordinates are RAS millimetres, as Slicer's scene holds them (a TRANSFORM is the tip's
pose, its z axis the insertion direction); timestamps are the wall-clock time of the
simulated instant (``start + t``), so every message of one instant carries the same one.
Slicer's OpenIGTLinkIF module shows them once connected: needlekit listens on ``PORT``
(Slicer's connector as client) or connects to ``HOST:PORT`` (Slicer's connector as
server); the default port is OpenIGTLink's 18944.

With a tip name (``--tip-from-igtl NAME``), :class:`IGTLTipSensor` takes the sensed tip
from the incoming TRANSFORMs of that name instead of the simulated sensor: a tracker behind
PLUS sends ``NeedleToTracker``. Each new message is a sample taken at its timestamp.

When the other end goes away (Slicer closed, a cable pulled), the link says so in one
logged line and stops sending; the insertion runs on and its record is written. pyigtl's
own connection loops would print a traceback there: the link runs its own (the same
reading and sending, through pyigtl's message code).

pyigtl is optional: ``pip install 'needlekit[igtl]'``.
"""

from __future__ import annotations

import logging
import math
import signal
import socket
import socketserver
import threading
import time

import numpy as np

from needlekit.control.em import EMSample
from needlekit.errors import InvalidInputError

__all__ = ["DEFAULT_PORT", "IGTLLink", "IGTLTipSensor", "parse_address"]

log = logging.getLogger(__name__)

#: OpenIGTLink's registered port.
DEFAULT_PORT: int = 18944
#: Messages left in pyigtl's outgoing queue (it holds 100) before the next instant's go in.
QUEUE_HIGH: int = 40
#: A received rotation block this close (Frobenius, of R^T R - I) to orthonormal is float32
#: rounding of a rotation, and is made one.
ROUNDING_TOL: float = 1e-4
#: Bytes packed but not yet taken by the socket, at most: about 2 s of the stream (an
#: instant is 4 messages, a few kB with the plan's points, 40 a second). Past it the other
#: end is not reading: what is queued is dropped (said once), so that the insertion, and
#: the tracker's samples coming the other way, never wait for it.
OUTBOX_BYTES: int = 256 * 1024


def parse_address(text: str) -> tuple[str | None, int]:
    """``[HOST:]PORT`` as (host or None, port).

    Parameters
    ----------
    text : str

    Returns
    -------
    (str or None, int)
        No host: listen on the port (this machine).

    Raises
    ------
    InvalidInputError
        (named ``--igtl``) Not a port in 1-65535, or an empty host.

    Examples
    --------
    >>> parse_address("18944"), parse_address("slicer.local:18945")
    ((None, 18944), ('slicer.local', 18945))
    """
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 1 <= number <= 65535 or (":" in text and not host):
        raise InvalidInputError(
            "--igtl", f"expected [HOST:]PORT with a port in 1-65535, got {text!r}"
        )
    return (host or None), number


def _pyigtl():
    try:
        import pyigtl
    except ImportError:
        raise InvalidInputError("--igtl", "needs pyigtl: pip install 'needlekit[igtl]'") from None
    return pyigtl


def _send_some(endpoint, sock) -> None:
    """Pack what is queued into the endpoint's outbox (at most :data:`OUTBOX_BYTES`; past
    it the queue is dropped) and give the socket what it takes now, never waiting on a
    peer that does not read (a message the socket took in part goes on where it stopped)."""
    box = endpoint.outbox
    with endpoint.lock_outgoing_messages:
        queue = endpoint.outgoing_messages
        while queue and len(box) < OUTBOX_BYTES:
            box += queue.popleft().pack()
        if queue and len(box) >= OUTBOX_BYTES:
            if not endpoint.dropped:
                log.warning("OpenIGTLink: the other end does not read what is sent; "
                            "messages are dropped, the insertion goes on")  # fmt: skip
            endpoint.dropped += len(queue)
            queue.clear()
    if box:
        try:
            taken = sock.send(box)
        except (TimeoutError, BlockingIOError):  # its buffer is full: next time round
            taken = 0
        del box[:taken]


def _serve(endpoint, sock) -> None:
    """Read what arrives and send what is queued until asked to stop or the connection
    fails (then one logged line, and ``endpoint.lost`` says why)."""
    endpoint.outbox = bytearray()
    try:
        while not endpoint.communication_thread_stop_requested:
            while endpoint._receive_message_from_socket(sock):
                if endpoint.communication_thread_stop_requested:
                    break
            _send_some(endpoint, sock)
    except Exception as exc:  # whatever the peer did: one line, no traceback
        endpoint.lost = f"{type(exc).__name__}: {exc}"
        endpoint._connected = False
        log.warning("OpenIGTLink: the connection failed (%s); streaming stops", endpoint.lost)


class _Handler(socketserver.BaseRequestHandler):
    """The server's loop for its client (:func:`_serve`)."""

    def handle(self) -> None:
        self.server._connected = True
        self.request.settimeout(0.01)
        _serve(self.server, self.request)


def _client(pyigtl, host: str, port: int):
    """A pyigtl client whose connection loop is :func:`_serve` (it connects, then serves
    until the connection fails, and does not connect again)."""

    class Client(pyigtl.OpenIGTLinkClient):
        def _client_thread_function(self) -> None:
            sock = None
            while not self.communication_thread_stop_requested and sock is None:
                try:
                    sock = socket.create_connection((host, port), timeout=0.5)
                except OSError:
                    time.sleep(0.01)
            if sock is not None:
                sock.settimeout(0.01)
                self._connected = True
                _serve(self, sock)
                sock.close()
            self.communication_thread_stopped = True

    client = Client(host=host, port=port, start_now=False)
    client.lost = None
    client.dropped = 0
    client.outbox = bytearray()
    client.start()
    return client


class IGTLLink:
    """One OpenIGTLink connection: a server on ``port`` (no host) or a client to
    ``host:port``.

    Parameters
    ----------
    address : str
        ``[HOST:]PORT`` (:func:`parse_address`).
    realtime : float
        Simulated seconds per wall-clock second (1: real time; 0: as fast as it runs).
    wait_s : float
        How long to wait for the other end before the insertion starts.

    Raises
    ------
    InvalidInputError
        pyigtl missing, or nobody connected within ``wait_s`` (named ``--igtl``).
    """

    def __init__(self, address: str, realtime: float = 1.0, wait_s: float = 30.0) -> None:
        host, port = parse_address(address)
        pyigtl = _pyigtl()
        self._messages = pyigtl
        if host is None:
            self.endpoint = pyigtl.OpenIGTLinkServer(port=port, local_server=True, start_now=False)
            self.endpoint.RequestHandlerClass = _Handler
            self.endpoint.lost = None
            self.endpoint.dropped = 0
            self.endpoint.outbox = bytearray()
            threading.Thread(target=self.endpoint.serve_forever, daemon=True).start()
        else:
            self.endpoint = _client(pyigtl, host, port)
        self.realtime = float(realtime)
        self.sent = 0
        deadline = time.monotonic() + wait_s
        while not self.endpoint.is_connected():
            if time.monotonic() > deadline:
                self.close()
                raise InvalidInputError(
                    "--igtl", f"nobody connected to {address} within {wait_s:g} s"
                )
            time.sleep(0.01)
        self.t0_wall = time.time()

    def stamp(self, t_s: float) -> float:
        """The wall-clock timestamp of simulated time ``t_s``.

        Parameters
        ----------
        t_s : float

        Returns
        -------
        float
            Seconds since the epoch.
        """
        return self.t0_wall + t_s

    def publish(self, t_s, true_pose, estimated_pose, plan_points_mm, state: dict) -> None:
        """Send one instant's messages (see the module notes), after waiting for its
        wall-clock time.

        Parameters
        ----------
        t_s : float
        true_pose, estimated_pose : ndarray, shape (4, 4)
        plan_points_mm : ndarray, shape (n, 3)
        state : dict
            As :class:`~needlekit.execute.run.LoopHooks` gives it.

        Returns
        -------
        None
        """
        if self.endpoint.lost is not None:  # said once, when it happened
            return
        if self.realtime > 0:
            wait = self.t0_wall + t_s / self.realtime - time.time()
            if wait > 0:
                time.sleep(wait)
        self._drain(QUEUE_HIGH)
        m, stamp = self._messages, self.stamp(t_s)
        pts = np.asarray(plan_points_mm, dtype=np.float32)
        text = (
            f"t={t_s:.3f} s inserted={state['inserted_mm']:.2f} mm goal="
            f"{state['goal_distance_mm']:.2f} mm replans={state['replans']} {state['phase']}"
        )
        for msg in (
            m.TransformMessage(np.array(estimated_pose, dtype=float), timestamp=stamp,
                               device_name="NeedleTip"),
            m.TransformMessage(np.array(true_pose, dtype=float), timestamp=stamp,
                               device_name="NeedleTipTrue"),
            m.PolyDataMessage(points=pts, lines=[len(pts), *range(len(pts))], timestamp=stamp,
                              device_name="NeedlePlan"),
            m.StringMessage(text, timestamp=stamp, device_name="NeedleState"),
        ):  # fmt: skip
            self.endpoint.send_message(msg, wait=False)
            self.sent += 1

    def flush(self, timeout_s: float = 5.0) -> None:
        """Wait until every queued message has gone out (or ``timeout_s`` passed).

        Parameters
        ----------
        timeout_s : float

        Returns
        -------
        None
        """
        self._drain(0, timeout_s)

    def _drain(self, most: int, timeout_s: float = 5.0) -> None:
        # pyigtl's queue drops its oldest messages when full: wait while it holds more than
        # ``most`` (a link faster than real time, or a slow reader)
        deadline = time.monotonic() + timeout_s
        ep = self.endpoint
        while time.monotonic() < deadline and ep.is_connected():
            with ep.lock_outgoing_messages:
                if len(ep.outgoing_messages) <= most and (most or not ep.outbox):
                    return
            time.sleep(0.001)

    def latest_transform(self, name: str):
        """The newest TRANSFORM named ``name`` received since the last call.

        Parameters
        ----------
        name : str

        Returns
        -------
        pyigtl.TransformMessage or None
        """
        msg = self.endpoint.wait_for_message(name, timeout=0)
        if msg is None or getattr(msg, "_message_type", "") != "TRANSFORM":
            return None
        return msg

    def close(self) -> None:
        """Stop the connection, and give back the signal handlers pyigtl's server took.

        Returns
        -------
        None
        """
        self.endpoint.stop()
        for sig, previous in getattr(self.endpoint, "_previous_signal_handlers", {}).items():
            signal.signal(sig, previous)


class IGTLTipSensor:
    """The sensed tip from incoming TRANSFORMs (:class:`~needlekit.execute.run.LoopHooks`'
    ``sensor``): each new message named ``name`` is a sample taken at its timestamp.

    The sensor passes on what arrives as it is (a repeated timestamp, a NaN, a matrix that
    is no pose): the loop's :class:`~needlekit.execute.guard.SensorGuard` judges it. A
    rotation block within float32's rounding of a rotation is made one.

    Parameters
    ----------
    link : IGTLLink
    name : str
        The tracker's transform, e.g. ``NeedleToTracker``.

    Attributes
    ----------
    received : int
    """

    def __init__(self, link: IGTLLink, name: str) -> None:
        self.link = link
        self.name = name
        self.received = 0

    def update(self, t: float, true_pose) -> EMSample | None:
        """The newest sample that has arrived by simulated time ``t`` (the simulated
        sensor's interface; ``true_pose`` is not used).

        Parameters
        ----------
        t : float
        true_pose : callable

        Returns
        -------
        EMSample or None
        """
        msg = self.link.latest_transform(self.name)
        if msg is None:
            return None
        self.received += 1
        pose = np.full((4, 4), np.nan)
        matrix = np.asarray(msg.matrix, dtype=np.float64)
        if matrix.shape == (4, 4):
            pose = matrix.copy()
        r = pose[:3, :3]
        if np.all(np.isfinite(r)) and np.linalg.norm(r.T @ r - np.eye(3)) < ROUNDING_TOL:
            u, _, vt = np.linalg.svd(r)  # the nearest rotation (sent as float32)
            pose[:3, :3] = u @ vt
        taken = float(msg.timestamp - self.link.t0_wall)
        return EMSample(min(taken, t) if math.isfinite(taken) else taken, t, pose)
