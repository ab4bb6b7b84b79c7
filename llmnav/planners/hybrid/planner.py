"""Hybrid planner: the model picks one numbered option; A* and the motion layer carry it out.

How the model picks (`--decide`): `score` ranks the options by the likelihood of their texts
(`llmnav.planners.hybrid.scoring`: SayCan-style, the decision rule is written there); `generate` asks for
an option number under a JSON Schema; `auto` (the default) scores where the backend can. The run's
`planner` event and summary record which mode ran.

Beyond the three sources. A small local model writes absurd free-form actions but can choose among a few
well-described options under a grammar (docs/sources.md, M), so each decision offers:
- go to a landmark — every labelled object when the scenario publishes its map (corridor worlds, as in
  the waypoint source), otherwise only objects the detector has seen (the nearest `max_landmarks`),
  each with distance, direction and (with `--menu-order relevance`) whether its name matches the task;
- explore a frontier cluster of the robot's own LiDAR map (the first `max_frontiers` by `-o explore`:
  nearest, most useful, or scored by what has been seen near it; not offered when the map is published);
- (scored decisions) a relational place between or beside landmarks already seen;
- rotate 360° to look around;
- finish.
The answer's schema restricts `option` to the listed numbers, and it still passes the guard.

Each option is one short line (`3. Go to oil barrel, 8 m front-right, visited`): whole metres and one of
eight directions, because the navigation stack does the driving and every digit is a token; what the
words mean is said once in the system prompt, which the prompt cache keeps. A decision after the first
then reads about 90–120 new prompt tokens (docs/fast-decisions.md).

What the planner knows follows the episode's information mode (llmnav.world.knowledge):
- `map` (corridor worlds): the published map's walls and objects; landmarks are its labelled objects.
- `sensed` (the default without a published map): pose from odometry, corrected by matching each LiDAR
  scan to its own LiDAR map (`-o localize=true`, the default; `llmnav.nav.localize`), which integrates
  the scans at the corrected poses; obstacles only from that map, unknown space blocked and inflated as
  the frontier baseline treats it; landmarks are positions estimated from detections (range and bearing,
  placed with the believed pose) and averaged as they are seen again; arrival is judged from those
  estimates. It never reads the scenario's objects, walls or goal points, nor the true pose.
- `oracle`: the true grid and goal points (how the planner worked before the modes existed).

The menu order (`--menu-order`): `distance` (default) is neutral: landmarks and frontiers by distance
(ties by kind, then name), then the full turn, then Finish, with no hint drawn from the task. `relevance`
is ordered for a weak model that favours the first and the last entry, using name matching of the task
against object names: while nothing the task names is known, looking around (once per spot) and
exploring come first; a named landmark comes first once known; at it, the menu shrinks to Finish (and one
more look); an unfinished task never lists Finish last.

The modules: `menu` builds the options, `prompt` asks for (or `scoring` scores) the choice, `execute`
carries it out through A* and the shared leg driver (`llmnav.guard.legs`), `memory` keeps the landmarks;
this module is the decide-execute loop.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, ClassVar

from llmnav.core.declarations import Declarations
from llmnav.errors import BadInputError
from llmnav.guard.legs import Action
from llmnav.mapping.frontiers import sensed_grid
from llmnav.mapping.grid import GridConfig, GridGeometry, LidarMap, build_grid, inflate, margins_from
from llmnav.planners.base import (
    MODEL_OPTIONS,
    DriveOptions,
    EpisodeContext,
    EpisodeOutcome,
    Information,
    Planner,
    StepInfo,
    decides_by_scores,
    fallback_mark,
)
from llmnav.planners.hybrid.config import HybridConfig
from llmnav.planners.hybrid.execute import Executor, with_seen_obstacles
from llmnav.planners.hybrid.memory import Memory, believed_pose, look, remember, start_memory
from llmnav.planners.hybrid.menu import MenuInputs, build_menu
from llmnav.planners.hybrid.options import HybridOptions
from llmnav.planners.hybrid.oracle import HybridAnswerKey
from llmnav.planners.hybrid.prompt import ask_choice, scored_choice, sends_image
from llmnav.planners.hybrid.scoring import ScoredChooser
from llmnav.planners.observe import observe

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.core.chat import AnswerKey
    from llmnav.core.geometry import Pose2D
    from llmnav.mapping.grid import OccupancyGrid
    from llmnav.planners.base import GroundTruth
    from llmnav.planners.hybrid.menu import Option


class HybridPlanner(Planner):
    """See the module docstring."""

    name = "hybrid"
    needs_backend = True
    Options = HybridOptions
    # from a published map, from its sensors, or (as before the information model) the true grid
    information_modes: ClassVar[tuple[Information, ...]] = ("sensed", "map", "oracle")
    grid_factors = ("decide", "menu_order", "sensing", "lidar_sectors", "localize")
    # explore as run: "utility (cannot score)" marks a backend that could not score frontiers
    condition_keys = ("decide", "sensing", "lidar_sectors", "localize", "explore")
    declares = Declarations(asks_model_every_decision=True)
    options = MODEL_OPTIONS | {
        "sensing",
        "lidar_sectors",
        "lidar_fov_deg",
        "max_iterations",
        "image_width",
        "image_height",
    }

    def __init__(self, config: HybridConfig | None = None) -> None:
        self.cfg = config or HybridConfig()

    @staticmethod
    def templates(options: DriveOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["hybrid_system", "hybrid_user"]

    def oracle_answers(self, truth: GroundTruth, options: DriveOptions) -> AnswerKey:
        """Scores and choices a perfect model would give (`llmnav.planners.hybrid.oracle`)."""
        return HybridAnswerKey(truth)

    def check_backend(self, backend: Backend, options: HybridOptions) -> None:
        """`--decide score` needs a backend that scores continuations."""
        if options.decide == "score" and not backend.can_score:
            raise BadInputError(
                f"--decide score: backend '{backend.spec}' cannot score option texts "
                "(use --decide generate, or a backend that scores: local, policy:*, a llama.cpp server)"
            )

    @staticmethod
    def decision_mode(ctx: EpisodeContext) -> str:
        """`score` or `generate`: what `--decide` means with this episode's backend."""
        return "score" if decides_by_scores(ctx.options, ctx.backend) else "generate"

    def explore_mode(self, ctx: EpisodeContext) -> str:
        """How this episode explores: `-o explore`, except that scored frontiers need scored decisions.

        A backend that cannot score (or `--decide generate`) explores by utility; the run's summary and
        condition say so ("utility (cannot score)"), so it is never taken for a scored run.
        """
        requested = ctx.options.explore
        if requested == "scored" and self.decision_mode(ctx) != "score":
            return "utility (cannot score)"
        return requested

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Decide, execute, repeat until the model finishes or the iteration budget runs out."""
        maps = _Maps(ctx, self.cfg)
        memory = start_memory(ctx)
        executor = Executor(ctx, self.cfg, maps.lidar_map, memory)
        # (The runner logs the start pose and every trajectory sample; nothing to hook here.)
        outcome = self._decide_and_execute(ctx, maps, memory, executor)
        executor.report_pose()  # where the planner believes the episode ended (the summary's pose error)
        return outcome

    def _decide_and_execute(
        self, ctx: EpisodeContext, maps: _Maps, memory: Memory, executor: Executor
    ) -> EpisodeOutcome:
        """The decide-execute loop of `run`."""
        world, scenario = ctx.world, ctx.scenario
        json_errors = vetoes = 0
        mode = self.decision_mode(ctx)
        bounds = scenario.bounds  # the extent the explorer may know: a bigger world gets more looks
        area = (bounds.x[1] - bounds.x[0]) * (bounds.y[1] - bounds.y[0])  # [m^2]
        mapped = bool(scenario.corridors)
        explore = self.explore_mode(ctx)
        # the condition as run: a fallback from auto to generation, or to utility for want of scores
        as_run = fallback_mark(ctx.options.decide, mode).get("condition", {})
        if explore != ctx.options.explore:
            as_run = {**as_run, "explore": explore}
        ctx.event(
            "planner",
            decide=mode,
            requested=ctx.options.decide,
            explore=explore,
            **({"condition": as_run} if as_run else {}),
        )
        chooser = (
            ScoredChooser(ctx, ctx.task.text, mapped=mapped, area_m2=area, explore=ctx.options.explore)
            if mode == "score"
            else None
        )
        done = {"json_errors": 0, "vetoes": 0, "decide": mode, "explore": explore}
        # Render the camera image only for a request that carries it (scored decisions send none),
        # unless the user keeps every frame for the viewer.
        frames = (mode == "generate" and sends_image(ctx)) or ctx.options.frames == "always"

        for step in range(1, ctx.options.max_iterations + 1):
            ctx.log.sim_time = world.sim_time
            obs = observe(world, ctx.options, ctx.log, step, image_needed=frames)
            pose = executor.sense(obs.scan)
            remember(ctx, memory, pose, obs.detections)
            if "detections" not in ctx.options.sensing:
                # The menu is built from what the detector sees, whether or not the model is shown it.
                look(ctx, memory)
            grids = maps.grids()
            options = build_menu(
                MenuInputs(ctx, self.cfg, grids, maps.lidar_map, memory, pose), scored=chooser is not None
            )
            reasoning = ""
            choice: int | None
            if chooser is not None:
                decision = scored_choice(ctx, chooser, options, memory, step)
                choice, errors, reasoning = decision.number, 0, decision.rule
            else:
                choice, errors = ask_choice(ctx, obs, options, memory, step, self.cfg.max_tokens)
            json_errors += errors
            done.update(json_errors=json_errors, vetoes=vetoes)
            if choice is None:
                return EpisodeOutcome(
                    "aborted",
                    f"no valid choice after {ctx.options.max_corrections} correction turns",
                    step,
                    dict(done),
                )
            if chooser is not None and decision.not_found:
                known = 1.0 - float(maps.lidar_map.unknown.mean())
                reason = f"not found: {decision.rule.removeprefix('not found: ')} (map {known:.0%} known)"
                return EpisodeOutcome("not_found", reason, step, dict(done))
            option = options[choice - 1]
            ctx.view.on_step(
                StepInfo(step, option.text, reasoning, front_m=obs.front_m, json_retries=errors, vetoes=vetoes)
            )
            if option.kind == "complete":
                Action(step, "COMPLETE", 0, pose, pose, option=option.text).log(ctx.log)
                return EpisodeOutcome("completed", "the model chose to finish", step, dict(done))
            before = believed_pose(ctx, memory)
            executed = executor.run(grids, option, step)
            # A refused leg put what blocked it on the map (the same choice detours); new objects in view
            # changed the menu: neither is a choice repeated without progress.
            if not executed.vetoes and not executed.saw_new:
                _drop_if_stuck(ctx, memory, option, before, executed.result, step)
            vetoes += executed.vetoes
            done.update(vetoes=vetoes)
            memory.last_result = executed.result
            if executed.collided:
                return EpisodeOutcome("failed", executed.result, step, dict(done))
        return EpisodeOutcome(
            "failed",
            f"no finish within {ctx.options.max_iterations} decisions",
            ctx.options.max_iterations,
            dict(done),
        )


def _drop_if_stuck(ctx: EpisodeContext, memory: Memory, option: Option, before: Pose2D, result: str, step: int) -> None:
    """An option that moved the robot nowhere leaves the menu, so the same choice never repeats without motion.

    (No path on the map, a leg refused at once.) A landmark becomes unreachable and a frontier is left off
    the menu, both until the next frontier is explored: the map grows, and a doorway whose floor was still
    unknown may then have a path (a frontier marked explored for good had hidden the rest of a building).
    """
    if option.kind not in ("landmark", "frontier") or option.goal is None:
        return
    after = believed_pose(ctx, memory)
    if after.distance_to(before.x, before.y) >= STUCK_M:
        return
    if option.landmark_id is not None or option.place is not None:
        memory.unreachable.add(option.key)
    else:
        memory.no_path.append(option.goal)
    ctx.log.sim_time = ctx.world.sim_time
    ctx.log.event("planner", kind="option_dropped", step=step, option=option.text, reason=result)


STUCK_M = 0.05  # [m] an option that moved the robot less than this made no progress


class _Maps:
    """The planning grids of one episode, rebuilt at each decision from what the LiDAR has seen.

    Sensed: the robot's own LiDAR map, unknown space blocked and inflated as the frontier baseline treats
    it. Otherwise the true grid plus whatever the LiDAR has hit away from every known solid. Two of each:
    a roomier one first, then the plain one.
    """

    def __init__(self, ctx: EpisodeContext, cfg: HybridConfig) -> None:
        scenario = ctx.scenario
        self.cfg = cfg
        self.bounds = scenario.bounds
        self.radius_m = ctx.world.robot.spec.radius_m
        plain = GridConfig()
        corner = self.radius_m + cfg.roomy_corner_m
        roomy = math.hypot(corner, corner) - self.radius_m + plain.resolution_m
        # Roomiest first, then the plain margin, then the narrow fallbacks a tight doorway needs (the leg check
        # and the collision monitor still keep the robot off its frame).
        self.margins = (max(plain.margin_m, roomy), *margins_from(plain.margin_m))
        self.lidar_map = LidarMap(GridGeometry.from_bounds(scenario.bounds, plain.resolution_m))
        self.static: list[OccupancyGrid] = []
        self.near_known: Any = None
        if ctx.information != "sensed":
            self.static = [build_grid(scenario, config=GridConfig(margin_m=m)) for m in self.margins]
            self.near_known = inflate(self.static[1].occupied, cfg.unexpected_m, self.lidar_map.geometry.resolution)

    def grids(self) -> list[OccupancyGrid]:
        """The planning grids as the map stands now, roomiest first."""
        if not self.static:
            return [sensed_grid(self.lidar_map, self.bounds, self.radius_m + m) for m in self.margins]
        return [with_seen_obstacles(g, self.lidar_map, self.near_known, self.cfg.unseen_depth_m) for g in self.static]
