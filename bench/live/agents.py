"""The load benchmark's fake agents: the sensor rig, the people they see, and the sending loop.

Every agent is a real ZeroMQ DEALER (``agent.link.AgentLink``) in one child process, sending
30 frames per second at its own random phase; the people are ``ProceduralPerformer`` bodies
moved into each sensor's frame.
"""

from __future__ import annotations

import heapq
import logging
import math
import multiprocessing as mp
import random
import time
from dataclasses import replace
from functools import partial
from multiprocessing.synchronize import Event as MpEvent
from typing import Any

import numpy as np
import numpy.typing as npt

from skelfuse.agent.link import AgentLink, RequestHandler
from skelfuse.agent.sim.depth_camera import KINECT_V2_DEPTH
from skelfuse.agent.sim.performer import ProceduralPerformer
from skelfuse.agent.sim.room import capture_point_cloud, default_room
from skelfuse.protocol.depth_cloud import DEFAULT_MAX_POINTS, decode_request, encode_reply
from skelfuse.protocol.skeleton import JOINT_COUNT, TrackingState
from skelfuse.protocol.transform import Matrix4, apply, invert, look_at_pose
from skelfuse.protocol.wire import Body, Frame, Hello

FPS = 30.0
PERIOD_S = 1.0 / FPS
SENSOR_RADIUS_M = 5.0
FloatArray = npt.NDArray[np.float64]


def sensor_layout(count: int) -> dict[str, Matrix4]:
    """``count`` sensors on a 5 m circle, 1 m high, all looking at the middle of the room."""
    poses: dict[str, Matrix4] = {}
    for i in range(count):
        angle = 2 * math.pi * i / count
        position = (SENSOR_RADIUS_M * math.sin(angle), 1.0, SENSOR_RADIUS_M * math.cos(angle))
        poses[f"load-{i + 1:02d}"] = look_at_pose(position, (0.0, 1.0, 0.0))
    return poses


class WorldMotion:
    """The performer's world joints at any instant: a 30 Hz grid, linearly interpolated.

    ``ProceduralPerformer.joints_at`` costs about 1 ms for six people; sampling it once per
    grid step instead of once per agent frame keeps the agents process light with 16 agents.
    """

    def __init__(self, bodies: int) -> None:
        self._performer = ProceduralPerformer(bodies)
        self._t0 = time.time()
        self._cache: dict[int, FloatArray] = {}

    def _grid(self, k: int) -> FloatArray:
        joints = self._cache.get(k)
        if joints is None:
            joints = self._performer.joints_at(k * PERIOD_S)
            self._cache[k] = joints
            for old in [key for key in self._cache if key < k - 2]:
                del self._cache[old]
        return joints

    def at(self, t_s: float) -> FloatArray:
        x = (t_s - self._t0) * FPS
        k = math.floor(x)
        a = x - k
        out: FloatArray = (1 - a) * self._grid(k) + a * self._grid(k + 1)
        return out


def hello(sensor_id: str) -> Hello:
    """What every fake agent says first: a simulated sensor at 30 fps, clock stamp now."""
    return Hello(sensor_id, "sim", "bench-load", FPS, time.time_ns())


def depth_handler(
    T_world_from_sensor: Matrix4, persons_world: FloatArray, seed: int
) -> RequestHandler:
    """A ``depth_cloud`` answer for one fake agent: the default room (its walls moved out past
    the sensors' circle) and ``persons_world`` seen from its pose by a simulated Kinect v2,
    rendered now (a few hundred ms), sent as is later.

    Raises (from the handler): DecodeError, a malformed request (the link answers a refusal).
    """
    points = capture_point_cloud(
        replace(default_room(), wall_half_m=SENSOR_RADIUS_M + 1, floor_half_m=SENSOR_RADIUS_M + 2),
        persons_world, T_world_from_sensor, np.random.default_rng(seed),
        max_points=DEFAULT_MAX_POINTS,
    )  # fmt: skip
    d = KINECT_V2_DEPTH
    intrinsics = {"width": d.width, "height": d.height, "fx": d.fx, "fy": d.fy, "cx": d.cx,
                  "cy": d.cy}  # fmt: skip

    def handle(params: dict[str, Any]) -> dict[str, object]:
        request = decode_request(params)
        return encode_reply(
            points[: request.max_points], t_capture_ns=time.time_ns(), intrinsics=intrinsics
        )

    return handle


def agents_process(
    endpoint: str,
    poses: dict[str, list[float]],
    bodies: int,
    seed: int,
    max_runtime_s: float,
    stop: MpEvent,
    results: mp.Queue[Any],
    log_path: str | None = None,
    depth: bool = False,
) -> None:
    """Run every fake agent in one thread, each on its own 30 fps schedule, until ``stop``.

    ``log_path``: the agents' warnings go there (e.g. "server silent"); ``depth``: each agent
    answers ``depth_cloud`` requests (rendered before the agents start).
    """
    import zmq

    if log_path is not None:
        logging.basicConfig(
            filename=log_path, level=logging.WARNING, format="%(asctime)s %(name)s %(message)s"
        )
    ids = sorted(poses)
    sensor_from_world = [invert(np.asarray(poses[s]).reshape(4, 4)) for s in ids]
    motion = WorldMotion(bodies)
    states = np.full(JOINT_COUNT, TrackingState.TRACKED, dtype=np.uint8)
    context: zmq.Context[Any] = zmq.Context()
    links = _links(endpoint, poses, context, motion if depth else None, seed)
    # Every link's socket, waited on between captures: a heartbeat is echoed when it comes,
    # as a real agent does (agent/capture_thread.py), not after that sensor's next frame.
    poller = zmq.Poller()
    link_of: dict[Any, int] = {}
    for j, link in enumerate(links):
        poller.register(link.socket, zmq.POLLIN)
        link_of[link.socket] = j
    rng = random.Random(seed)
    start = time.time() + 0.05
    due: list[tuple[float, int]] = [(start + rng.random() * PERIOD_S, i) for i in range(len(ids))]
    heapq.heapify(due)
    seqs = [0] * len(ids)
    captures: list[list[float]] = [[] for _ in ids]
    dropped_registered = [0] * len(ids)
    late = 0
    deadline = time.monotonic() + max_runtime_s
    while not stop.is_set() and time.monotonic() < deadline:
        when, i = due[0]
        now = time.time()
        if when > now:
            # Answer the server's heartbeats while waiting, as a real agent's link does.
            for ready, _ in poller.poll(round(min(when - now, 0.02) * 1000)):
                links[link_of[ready]].poll(0.0)
            continue
        heapq.heappop(due)
        t_ns = time.time_ns()
        seqs[i] += 1
        frame = _frame(seqs[i], t_ns, i, sensor_from_world[i], motion.at(t_ns / 1e9), states)
        registered = links[i].registered
        if links[i].send_frame(frame):
            captures[i].append(t_ns / 1e9)
        elif registered:
            dropped_registered[i] += 1
        links[i].poll(0.0)
        nxt = when + PERIOD_S
        if nxt < now - PERIOD_S:  # this process fell more than a frame behind: skip ahead
            late += 1
            nxt = now + PERIOD_S
        heapq.heappush(due, (nxt, i))
    out = {
        s: _agent_figures(links[i], seqs[i], dropped_registered[i], captures[i])
        for i, s in enumerate(ids)
    }
    for link in links:
        link.close()
    context.term()
    results.put({"agents": out, "late": late})


def _frame(
    seq: int,
    t_ns: int,
    agent: int,
    sensor_from_world: Matrix4,
    world: npt.NDArray[np.float64],
    states: npt.NDArray[np.uint8],
) -> Frame:
    """Agent number ``agent``'s frame ``seq`` captured at ``t_ns`` (ns since the epoch): the
    (B, 25, 3) ``world`` bodies in its frame, body ids ``agent·100 + 1..B``."""
    return Frame(
        seq,
        t_ns,
        tuple(
            Body(agent * 100 + b + 1, apply(sensor_from_world, world[b]).astype(np.float32), states)
            for b in range(len(world))
        ),
    )


def _links(
    endpoint: str,
    poses: dict[str, list[float]],
    context: Any,
    depth_of: WorldMotion | None,
    seed: int,
) -> list[AgentLink]:
    """One link per sensor (sorted by id); with ``depth_of``, each answers ``depth_cloud``
    requests with a cloud of the room and its people now, rendered here."""
    ids = sorted(poses)
    handlers: list[dict[str, RequestHandler]] = [{} for _ in ids]
    if depth_of is not None:
        people = depth_of.at(time.time())
        for i, s in enumerate(ids):
            pose = np.asarray(poses[s], dtype=np.float64).reshape(4, 4)
            handlers[i] = {"depth_cloud": depth_handler(pose, people, seed * 100 + i)}
    return [
        AgentLink(endpoint, partial(hello, s), context=context, handlers=handlers[i])
        for i, s in enumerate(ids)
    ]


def _agent_figures(
    link: AgentLink, captured: int, dropped_registered: int, captures: list[float]
) -> dict[str, Any]:
    """One agent's counts, and its frames' capture times (s since the epoch)."""
    return {
        "captured": captured,
        "sent": link.stats.frames_sent,
        "dropped_unregistered": link.stats.frames_dropped - dropped_registered,
        "dropped_registered": dropped_registered,
        "registrations": link.stats.registrations,
        "captures": captures,
    }
