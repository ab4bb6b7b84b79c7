"""`--realtime`: physics paced to the wall clock; without it the simulation runs as fast as it can."""

from __future__ import annotations

import time

from llmnav.core.geometry import Pose2D
from llmnav.sim.world import World
from llmnav.world.scenario import load_scenario


def test_realtime_world_takes_at_least_its_simulated_time():
    with World(load_scenario("corridor_a")) as world:
        world.reset(Pose2D(0.0, 0.0, 0.0))
        world.realtime = True
        started = time.perf_counter()
        world.step(240)  # 1 s of simulated time
        assert time.perf_counter() - started >= 0.95


def test_fast_world_is_not_paced():
    with World(load_scenario("corridor_a")) as world:
        world.reset(Pose2D(0.0, 0.0, 0.0))
        started_cpu = time.process_time()
        started = time.perf_counter()
        world.step(240)
        # Not a speed target: only that nothing sleeps (wall time stays close to the CPU time spent).
        assert (time.perf_counter() - started) - (time.process_time() - started_cpu) < 0.5
