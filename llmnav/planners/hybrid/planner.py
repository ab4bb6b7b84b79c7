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
- explore a frontier cluster of the robot's own LiDAR map (the nearest `max_frontiers`; not offered
  when the map is published);
- rotate 360° to look around;
- finish.
The answer's schema restricts `option` to the listed numbers, and it still passes the guard.

Each option is one short line (`3. Go to oil barrel, 8 m front-right, visited`): whole metres and one of
eight directions, because the navigation stack does the driving and every digit is a token; what the
words mean is said once in the system prompt, which the prompt cache keeps. A decision after the first
then reads about 90–120 new prompt tokens (docs/fast-decisions.md).

What the planner knows follows the episode's information mode (llmnav.knowledge):
- `map` (corridor worlds): the published map's walls and objects; landmarks are its labelled objects.
- `sensed` (the default without a published map): pose from odometry; obstacles only from its own LiDAR
  map, unknown space blocked and inflated as the frontier baseline treats it; landmarks are positions
  estimated from detections (range and bearing, placed with the odometry pose) and averaged as they are
  seen again; arrival is judged from those estimates. It never reads the scenario's objects, walls or
  goal points, nor the true pose.
- `oracle`: the true grid and goal points (how the planner worked before the modes existed).

The menu order (`--menu-order`): `distance` (default) is neutral: landmarks and frontiers by distance
(ties by kind, then name), then the full turn, then Finish, with no hint drawn from the task. `relevance`
is ordered for a weak model that favours the first and the last entry, using name matching of the task
against object names: while nothing the task names is known, looking around (once per spot) and
exploring come first; a named landmark comes first once known; at it, the menu shrinks to Finish (and one
more look); an unfinished task never lists Finish last.

The chosen option runs through A* and `Motion.go_to`. Paths are planned on a grid roomy enough for the
veto's swept rectangle (falling back to the plain grid), plus whatever the LiDAR has hit away from every
known solid. Every straight leg is checked by the safety veto first; a blocked leg ends the option and the
model is told, and the same option then plans around what was seen. A robot standing inside the wall
clearance first steps out to the nearest free cell. Exploring ends early when something the task names
comes into view, so the model decides again with the new information.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from llmnav.chat import ChatRequest, Message
from llmnav.declarations import Declarations
from llmnav.errors import BadInputError
from llmnav.geometry import Pose2D
from llmnav.planners.base import MODEL_OPTIONS, DriveOptions, EpisodeContext, EpisodeOutcome, Planner, StepInfo

# [m] goals for a frontier lie within the grid's inflation plus this of one of its cells (sensed mode:
# unknown space is inflated, so the frontier cells themselves are never free)
FRONTIER_GOAL_BAND_M = 0.25

if TYPE_CHECKING:
    from llmnav.backends.base import Backend
    from llmnav.chat import AnswerKey
    from llmnav.guard.schemas import HybridChoice
    from llmnav.mapping.grid import LidarMap, OccupancyGrid
    from llmnav.observe import Observation
    from llmnav.planners.base import GroundTruth
    from llmnav.scenario import Scenario
    from llmnav.sim.motion import MotionResult
    from llmnav.sim.sensors import Detection

OptionKind = Literal["landmark", "frontier", "scan", "complete"]


@dataclass(frozen=True)
class HybridConfig:
    """Numbers of the hybrid planner."""

    approach_min_m: float = 0.8  # [m] closest stand-off to an object without a goal point
    approach_max_m: float = 1.8  # [m] farthest stand-off (inside the score's 2.5 m full-credit radius)
    # [m] a landmark the motion layer will not let the robot approach further counts as reached within
    # this: the stepwise source's instruction to stop 1.5-2.5 m from the target
    stop_within_m: float = 2.5
    leg_max_m: float = 1.5  # [m] longest straight leg between veto checks and detector looks
    # Options offered per decision: a short menu keeps every decision within ~120 new prompt tokens and
    # is an easier choice; farther landmarks come back into the menu as the robot moves.
    max_landmarks: int = 4
    max_frontiers: int = 2
    frontier_min_cells: int = 12  # smaller frontier clusters are noise
    veto_margin_m: float = 0.05  # [m] lateral margin of the veto's swept corridor
    # [m] the veto's stop margin: below the grid's 0.10 m clearance, so a leg ending at a free cell that
    # faces a known wall passes, while anything the static map lacks on the path still blocks it
    veto_stop_margin_m: float = 0.05
    unexpected_m: float = 0.10  # [m] LiDAR hits farther than this from every known solid are obstacles
    # [m] extra clearance around such hits: the LiDAR sees only an obstacle's near face, not its depth
    unseen_depth_m: float = 0.25
    obstacle_stop_m: float = 0.35  # [m] go_to stops when something is this close ahead
    # [tokens] the option number comes first and is complete after ~6 tokens; the cap keeps the reasoning
    # short (the guard closes a cut-off string), which on a loaded CPU saves seconds per decision
    max_tokens: int = 16
    arrived_m: float = 0.3  # [m] within this of a visited landmark's stand point the robot is "there"
    rescan_m: float = 1.0  # [m] a full turn within this of the last one shows nothing new: not offered


@dataclass
class Option:
    """One numbered choice and how to carry it out."""

    number: int
    kind: OptionKind
    text: str
    goal: tuple[float, float] | None = None  # [m] where to drive
    face: tuple[float, float] | None = None  # [m] what to face on arrival
    landmark_id: str | None = None
    name: str = ""  # the landmark's name, for the result line
    at: tuple[str, ...] = ()  # Finish: the names of the landmarks the robot stands at
    distance_m: float = 0.0  # [m] from the robot to `goal`
    standing: bool = False  # landmark: the robot is there (at its stand point, or as close as is safe)

    @property
    def goal_name(self) -> str:
        """What the option drives to, in a few words."""
        return self.name or ("the explored edge" if self.kind == "frontier" else "the goal")


@dataclass
class Memory:
    """What the planner knows across decisions."""

    landmarks: dict[str, tuple[float, float]] = field(default_factory=dict)  # id -> estimated position [m]
    labels: dict[str, str] = field(default_factory=dict)  # id -> the name the detector (or map) gives it
    sightings: dict[str, tuple[float, float, int]] = field(default_factory=dict)  # id -> (sum x, sum y, n)
    visited: set[str] = field(default_factory=set)
    wanted: set[str] = field(default_factory=set)  # objects the task names
    scans: int = 0  # full turns made so far
    scanned_at: tuple[float, float] | None = None  # [m] where the last full turn was made
    explored: list[tuple[float, float]] = field(default_factory=list)  # [m] frontier goals reached
    # id -> [m] the closest spot to a landmark the motion layer let the robot reach (it refused the rest)
    closest: dict[str, tuple[float, float]] = field(default_factory=dict)
    refused: dict[str, tuple[float, float]] = field(default_factory=dict)  # id -> [m] where a trip was refused
    unreachable: set[str] = field(default_factory=set)  # refused twice from the same spot, far from it
    last_result: str = "nothing yet"


class HybridPlanner(Planner):
    """See the module docstring."""

    name = "hybrid"
    needs_backend = True
    declares = Declarations(asks_model_every_decision=True)
    options = MODEL_OPTIONS | {
        "sensing",
        "lidar_sectors",
        "lidar_fov_deg",
        "max_iterations",
        "image_width",
        "image_height",
        "decide",
    }

    def __init__(self, config: HybridConfig | None = None) -> None:
        self.cfg = config or HybridConfig()

    @staticmethod
    def templates(options: DriveOptions) -> list[str]:
        """Prompt templates this planner renders (their hashes go into the run config)."""
        return ["hybrid_system", "hybrid_user"]

    def oracle_answers(self, truth: GroundTruth, options: DriveOptions) -> AnswerKey:
        """Scores and choices a perfect model would give (`llmnav.planners.hybrid.oracle`)."""
        from llmnav.planners.hybrid.oracle import HybridAnswerKey

        return HybridAnswerKey(truth)

    def check_backend(self, backend: Backend, options: DriveOptions) -> None:
        """`--decide score` needs a backend that scores continuations."""
        if options.decide == "score" and not backend.can_score:
            raise BadInputError(
                f"--decide score: backend '{backend.spec}' cannot score option texts "
                "(use --decide generate, or a backend that scores: local, policy:*, a llama.cpp server)"
            )

    @staticmethod
    def decision_mode(ctx: EpisodeContext) -> str:
        """`score` or `generate`: what `--decide` means with this episode's backend."""
        return "score" if ctx.decides_by_scores() else "generate"

    def run(self, ctx: EpisodeContext) -> EpisodeOutcome:
        """Decide, execute, repeat until the model finishes or the iteration budget runs out."""
        from llmnav.mapping.grid import GridConfig, GridGeometry, LidarMap, build_grid, inflate
        from llmnav.observe import observe
        from llmnav.planners.hybrid.scoring import ScoredChooser
        from llmnav.tasks import named_objects

        world, scenario = ctx.world, ctx.scenario
        sensed = ctx.information == "sensed"
        # A roomier grid whose paths and stand points the veto accepts: its swept rectangle reaches
        # `hypot(stop + r, r + margin)` from a leg's end, more than a round robot's clearance on `grid`.
        radius = world.robot.spec.radius_m
        reach = math.hypot(self.cfg.veto_stop_margin_m + radius, radius + self.cfg.veto_margin_m)
        geometry = GridGeometry.from_bounds(scenario.bounds, GridConfig().resolution_m)
        margins = (max(GridConfig().margin_m, reach - radius + geometry.resolution), GridConfig().margin_m)
        lidar_map = LidarMap(geometry)
        if sensed:
            static: list[OccupancyGrid] = []
            near_known = None
            memory = Memory()
        else:
            static = [build_grid(scenario, config=GridConfig(margin_m=m)) for m in margins]
            near_known = inflate(static[1].occupied, self.cfg.unexpected_m, geometry.resolution)
            wanted = {o.id for o in named_objects(scenario, ctx.task.text)} if self._relevance(ctx) else set()
            memory = Memory(wanted=wanted, labels={o.id: o.label for o in scenario.objects})
            if scenario.corridors:  # a published map: every labelled object is known up front
                memory.landmarks = {o.id: o.goal_point for o in scenario.objects}
        # (The runner logs the start pose and every trajectory sample; nothing to hook here.)
        json_errors = vetoes = 0
        mode = self.decision_mode(ctx)
        ctx.event("planner", decide=mode, requested=ctx.options.decide)
        chooser = ScoredChooser(ctx, ctx.task.text, mapped=bool(scenario.corridors)) if mode == "score" else None
        done = {"json_errors": 0, "vetoes": 0, "decide": mode}

        for step in range(1, ctx.options.max_iterations + 1):
            ctx.log.sim_time = world.sim_time
            obs = observe(world, ctx.options, ctx.log, step)
            pose = obs.odom if sensed else obs.pose
            lidar_map.integrate(pose, obs.scan)
            self._remember(ctx, memory, pose, obs.detections)
            if "detections" not in ctx.options.sensing:
                # The menu is built from what the detector sees, whether or not the model is shown it.
                self._look(ctx, memory)
            if sensed:
                grids = [_sensed_grid(lidar_map, scenario, radius + m) for m in margins]
            else:
                grids = [_with_seen_obstacles(g, lidar_map, near_known, self.cfg.unseen_depth_m) for g in static]
            options = self._options(ctx, grids, lidar_map, memory, pose, scored=chooser is not None)
            reasoning = ""
            if chooser is not None:
                decision = self._scored(ctx, chooser, options, memory, step)
                choice, errors, reasoning = decision.number, 0, decision.rule
            else:
                choice, errors = self._choose(ctx, obs, pose, options, memory, step)
            json_errors += errors
            done.update(json_errors=json_errors, vetoes=vetoes)
            if choice is None:
                return EpisodeOutcome(
                    "aborted",
                    f"no valid choice after {ctx.options.max_corrections} correction turns",
                    step,
                    dict(done),
                )
            option = options[choice - 1]
            ctx.view.on_step(
                StepInfo(step, option.text, reasoning, front_m=obs.front_m, json_retries=errors, vetoes=vetoes)
            )
            if option.kind == "complete":
                ctx.log.event(
                    "action",
                    step=step,
                    command="COMPLETE",
                    parameters=0,
                    option=option.text,
                    pose_before=pose.as_list(),
                    pose_after=pose.as_list(),
                    collided=False,
                )
                return EpisodeOutcome("completed", "the model chose to finish", step, dict(done))
            result_text, vetoed, collided = self._execute(ctx, grids, lidar_map, option, memory, step)
            vetoes += vetoed
            done.update(vetoes=vetoes)
            memory.last_result = result_text
            if collided:
                return EpisodeOutcome("failed", result_text, step, dict(done))
        return EpisodeOutcome(
            "failed",
            f"no finish within {ctx.options.max_iterations} decisions",
            ctx.options.max_iterations,
            dict(done),
        )

    @staticmethod
    def _scored(ctx: EpisodeContext, chooser: Any, options: list[Option], memory: Memory, step: int) -> Any:
        """The scored decision on this menu (`llmnav.planners.hybrid.scoring`), logged as a `decision` event."""
        from llmnav.planners.hybrid.scoring import Candidate

        candidates = [
            Candidate(
                o.number,
                o.kind,
                (o.name,) if o.kind == "landmark" and o.name else o.at,
                o.distance_m,
            )
            for o in options
        ]
        decision = chooser.choose(candidates, turned=memory.scans > 0, step=step)
        ctx.event("decision", step=step, **decision.to_log())
        return decision

    # --- perception memory ----------------------------------------------------------------------
    def _remember(self, ctx: EpisodeContext, memory: Memory, pose: Pose2D, detections: list[Detection]) -> set[str]:
        """Add detections seen from `pose` to the landmark memory; the ids it did not know before.

        Sensed: each landmark is the mean of its estimates so far (noise averages out as it is seen
        again). Otherwise the latest estimate stands (a published map's position is never replaced).
        """
        from llmnav.tasks import names_in_text

        new: set[str] = set()
        for det in detections:
            oid = det.object_id
            if oid not in memory.landmarks:
                new.add(oid)
            seen = _estimate(pose, det.bearing_deg, det.distance_m)
            if ctx.information == "sensed":
                sx, sy, n = memory.sightings.get(oid, (0.0, 0.0, 0))
                memory.sightings[oid] = (sx + seen[0], sy + seen[1], n + 1)
                memory.landmarks[oid] = ((sx + seen[0]) / (n + 1), (sy + seen[1]) / (n + 1))
                memory.labels.setdefault(oid, det.label)
                if self._relevance(ctx) and names_in_text([det.label], ctx.task.text):
                    memory.wanted.add(oid)
            elif oid in new or not ctx.scenario.corridors:
                memory.landmarks[oid] = seen
        return new

    @staticmethod
    def _relevance(ctx: EpisodeContext) -> bool:
        return ctx.options.menu_order == "relevance"

    def _label(self, ctx: EpisodeContext, memory: Memory, object_id: str) -> str:
        return memory.labels.get(object_id, object_id)

    # --- the menu -------------------------------------------------------------------------------
    def _options(
        self,
        ctx: EpisodeContext,
        grids: list[OccupancyGrid],
        lidar_map: LidarMap,
        memory: Memory,
        pose: Pose2D,
        scored: bool = False,
    ) -> list[Option]:
        """The numbered menu; `grids` are the planning grids, roomiest first (`scored`: no cap on landmarks)."""
        wanted = memory.wanted
        options: list[Option] = []
        ranked = sorted(
            memory.landmarks.items(),
            key=lambda item: (item[0] not in wanted, pose.distance_to(*item[1])),
        )
        sensed = ctx.information == "sensed"
        # The cap counts places to drive to: the landmark the robot stands at is listed besides them (as
        # Finish's "at", or as "you are there"), and one without a reachable stand point is not listed.
        places = 0
        for object_id, position in ranked:
            if object_id in memory.unreachable:
                continue
            # Scored decisions read no prompt: every known landmark stays on the menu.
            if places >= self.cfg.max_landmarks and not scored:
                break
            # Sensed: the detector measures to the object's goal point, so the estimate is that point.
            true_goal = None if sensed else ctx.scenario.object(object_id).goal
            goal = self._approach(grids, position if sensed else true_goal, position, pose)
            if goal is None:
                continue
            # Where the motion layer refused to go closer, the spot it allowed counts as arrival.
            allowed = memory.closest.get(object_id)
            standing = pose.distance_to(*goal) <= self.cfg.arrived_m or (
                allowed is not None and pose.distance_to(*allowed) <= self.cfg.arrived_m
            )
            places += not standing
            notes = []
            # Near its stand point the bearing to the point says nothing: say where the robot is instead.
            notes.append("you are there" if standing else _where(pose, goal))
            if object_id in wanted:
                notes.append("name matches task")
            if object_id in memory.visited:
                notes.append("visited")
            name = self._label(ctx, memory, object_id)
            options.append(
                Option(
                    0,
                    "landmark",
                    f"Go to {name}, {', '.join(notes)}",
                    goal=goal,
                    face=position if sensed else ctx.scenario.object(object_id).center,
                    landmark_id=object_id,
                    name=name,
                    distance_m=pose.distance_to(*goal),
                    standing=standing,
                )
            )
        # With a published map every landmark is listed already: exploring would only distract the model.
        frontiers = [] if ctx.scenario.corridors else self._frontiers(grids[0], lidar_map, pose, sensed)
        # A frontier the robot stands at, or one it has reached before, shows nothing new from there (its
        # unknown side cannot be seen from the free cells): offering it again only wastes decisions.
        frontiers = [
            (centre, size)
            for centre, size in frontiers
            if pose.distance_to(*centre) > self.cfg.arrived_m
            and all(math.dist(centre, seen) > self.cfg.rescan_m for seen in memory.explored)
        ]
        for centre, _size in frontiers[: self.cfg.max_frontiers]:
            options.append(
                Option(
                    0,
                    "frontier",
                    f"Explore, {_where(pose, centre)}",
                    goal=centre,
                    distance_m=pose.distance_to(*centre),
                )
            )
        # The words say what the robot does (a task may ask for the turn itself, in any wording).
        scan = Option(0, "scan", "Turn a full circle to look around")
        scanned_here = memory.scanned_at is not None and pose.distance_to(*memory.scanned_at) < self.cfg.rescan_m
        # A second full turn on the same spot shows nothing new (the world is static): not offered.
        turn = [] if scanned_here else [scan]
        if not self._relevance(ctx):
            # Neutral: every place by distance (ties: landmarks first, then by name), a look, then Finish.
            # Going to where the robot already stands does nothing, so that entry becomes a fact in the
            # Finish line instead (whatever the task is).
            here = [o for o in options if o.kind == "landmark" and o.standing]
            moves = sorted(
                (o for o in options if o not in here),
                key=lambda o: (
                    round(pose.distance_to(*o.goal), 1) if o.goal is not None else 0.0,
                    o.kind != "landmark",
                    o.text,
                ),
            )
            at = ", ".join(o.name for o in here)
            finish = Option(0, "complete", "Finish" + (f" (at {at})" if at else ""), at=tuple(o.name for o in here))
            options = [*moves, *turn, finish]
            for number, option in enumerate(options, start=1):
                option.number = number
            return options
        options.append(scan)
        arrived = [
            o
            for o in options
            if o.landmark_id in wanted
            and o.landmark_id in memory.visited
            and o.standing
        ]
        # A task that names nothing (turn around, look around) is served by the scan, then by finishing.
        turning_task = not wanted and ctx.task.kind in ("rotate", "explore")
        if arrived:
            done = f" (at {arrived[0].name})"
        elif turning_task and memory.scans:
            done = " (you have looked around)"
        else:
            done = ""
        finish = Option(0, "complete", "Finish" + done, at=tuple(o.name for o in arrived))
        # Most relevant first: small models lean heavily toward option 1. While nothing the task names is
        # known, looking around (once per spot) and exploring come before unrelated landmarks.
        useful = [o for o in options if o.kind == "landmark" and o.landmark_id in wanted and o not in arrived]
        # Going to where the robot already stands does nothing: once there, that entry only distracts.
        others = [o for o in options if o.kind == "landmark" and o not in useful and o not in arrived]
        frontier = [o for o in options if o.kind == "frontier"]
        if done:
            # At what the task names (or after the asked-for turn) nothing else serves the task: a short
            # menu keeps a weak model from wandering off (measured: it did, at random, from a full one).
            options = [finish, *turn]
        elif turning_task:
            options = [*turn, *others, *frontier, finish]
        elif useful:
            options = [*useful, *others, *frontier, *turn, finish]
        else:
            options = [*turn, *frontier, *others, finish]
        if not done and len(options) >= 3:
            # The tiny model also favours the last entry; finishing early is the one unrecoverable
            # mistake, so an unfinished task never lists Finish last.
            options[-2], options[-1] = options[-1], options[-2]
        for number, option in enumerate(options, start=1):
            option.number = number
        return options

    def _approach(
        self,
        grids: list[OccupancyGrid],
        goal: tuple[float, float] | None,
        position: tuple[float, float],
        pose: Pose2D,
    ) -> tuple[float, float] | None:
        """Where to stand: the goal point if the robot fits there, else the nearest free stand-off cell.

        The stand-off cell comes from the roomiest grid that has one.
        """
        import numpy as np

        if goal is not None and grids[-1].is_free(*goal):
            return goal
        for grid in grids:
            xs, ys = grid.geometry.centres()
            ring = np.hypot(xs - position[0], ys - position[1])
            ok = (~grid.blocked) & (ring >= self.cfg.approach_min_m) & (ring <= self.cfg.approach_max_m)
            if ok.any():
                cost = np.where(ok, np.hypot(xs - pose.x, ys - pose.y), np.inf)
                row, col = np.unravel_index(int(np.argmin(cost)), cost.shape)
                return grid.geometry.cell_to_world(int(row), int(col))
        return None

    def _frontiers(
        self, grid: OccupancyGrid, lidar_map: LidarMap, pose: Pose2D, sensed: bool = False
    ) -> list[tuple[tuple[float, float], int]]:
        """Frontier clusters (known-free cells next to unknown ones), as reachable target points and sizes.

        With a static map the point is the cluster cell nearest its centroid (free, on the frontier). Sensed,
        unknown space is inflated, so no frontier cell is free: the point is the free cell within the
        inflation plus `FRONTIER_GOAL_BAND_M` of the cluster that lies nearest its centroid.
        """
        import numpy as np
        from scipy import ndimage

        free = lidar_map.free if sensed else lidar_map.free & ~grid.blocked
        unknown = lidar_map.unknown
        frontier = free & ndimage.binary_dilation(unknown, structure=np.ones((3, 3), bool))
        labels, count = ndimage.label(frontier, structure=np.ones((3, 3), bool))
        if sensed and count:
            distance, (near_r, near_c) = ndimage.distance_transform_edt(labels == 0, return_indices=True)
            reach = (grid.inflation_m + FRONTIER_GOAL_BAND_M) / grid.geometry.resolution
            # Each free cell near a frontier serves the cluster of its nearest frontier cell.
            goal_label = np.where((distance <= reach) & ~grid.blocked, labels[near_r, near_c], 0)
        out: list[tuple[tuple[float, float], int]] = []
        for index in range(1, count + 1):
            rows, cols = np.nonzero(labels == index)
            if rows.size < self.cfg.frontier_min_cells:
                continue
            centre_r, centre_c = rows.mean(), cols.mean()
            if sensed:
                rows_g, cols_g = np.nonzero(goal_label == index)
                if rows_g.size == 0:
                    continue
                best = int(np.argmin((rows_g - centre_r) ** 2 + (cols_g - centre_c) ** 2))
                point = grid.geometry.cell_to_world(int(rows_g[best]), int(cols_g[best]))
            else:
                best = int(np.argmin((rows - centre_r) ** 2 + (cols - centre_c) ** 2))
                point = grid.geometry.cell_to_world(int(rows[best]), int(cols[best]))
            out.append((point, int(rows.size)))
        out.sort(key=lambda item: pose.distance_to(*item[0]))
        return out

    # --- asking the model ---------------------------------------------------------------------
    def _choose(
        self, ctx: EpisodeContext, obs: Observation, pose: Pose2D, options: list[Option], memory: Memory, step: int
    ) -> tuple[int | None, int]:
        """The model's option number through the guard (bounded corrections); (None, errors) on failure."""
        from llmnav.guard.ask import GuardedAnswer, ask_guarded
        from llmnav.guard.schemas import hybrid_choice_model, response_schema
        from llmnav.prompting import render

        model = hybrid_choice_model(tuple(o.number for o in options))
        schema = response_schema(model)
        # The choice first: a small model that rambles in `reasoning` until the token cap has then still
        # chosen, and the guard's repair closes the cut-off string.
        schema["properties"] = {"option": schema["properties"]["option"]} | {
            k: v for k, v in schema["properties"].items() if k != "option"
        }
        if "required" in schema:
            schema["required"] = ["option", *[k for k in schema["required"] if k != "option"]]
        menu = "\n".join(f"{o.number}. {o.text}" for o in options)
        system = render("hybrid_system", robot=ctx.world.robot.spec.name)
        # Only the detections are shown: the LiDAR feeds the map and the veto (its sector table would
        # triple the prompt), and an image travels beside the text to a multimodal backend.
        user = render(
            "hybrid_user",
            task=ctx.task.text,
            last_result=memory.last_result,
            observation=f"{obs.detections_text}\n" if obs.detections_text else "",
            options=menu,
        )
        images = (obs.image,) if obs.image is not None and ctx.backend is not None and ctx.backend.multimodal else ()
        request = ChatRequest(
            (Message("system", system), Message("user", user, images)),
            schema,
            ctx.options.temperature,
            min(ctx.options.max_tokens, self.cfg.max_tokens),
            ctx.options.seed,
        )
        answer: GuardedAnswer[HybridChoice] = ask_guarded(
            ctx, request, model, None, ctx.options.max_corrections, step=step, purpose="choice"
        )
        errors = answer.attempts - (1 if answer.ok else 0)
        return (int(answer.value.option) if answer.value is not None else None), errors

    # --- carrying an option out ------------------------------------------------------------------
    def _execute(
        self,
        ctx: EpisodeContext,
        grids: list[OccupancyGrid],
        lidar_map: LidarMap,
        option: Option,
        memory: Memory,
        step: int,
    ) -> tuple[str, int, bool]:
        """Run one option; returns (what happened, vetoes, collided)."""
        world = ctx.world
        before = self._pose(ctx)
        if option.kind == "scan":
            new = False
            for _ in range(4):
                result = world.motion.rotate(math.pi / 2)
                new |= bool(self._look(ctx, memory))
                if result.collided:
                    break
            memory.scans += 1
            memory.scanned_at = (before.x, before.y)
            self._log_action(ctx, step, "SCAN", 360.0, before, result)
            return "looked around, " + ("new objects in view" if new else "nothing new"), 0, result.collided
        assert option.goal is not None
        legs = next((p for p in (self._plan(g, before, option.goal) for g in grids) if p is not None), None)
        if legs is None:
            return f"no collision-free path ({option.goal_name})", 0, False
        for x, y in legs:
            pose = self._pose(ctx)
            turn = math.remainder(math.atan2(y - pose.y, x - pose.x) - pose.yaw, math.tau)
            if abs(turn) > 0.087:
                world.motion.rotate(turn)
            length = self._pose(ctx).distance_to(x, y)
            verdict = self._veto(ctx, lidar_map, length)
            if verdict is not None:
                ctx.log.event("guard", step=step, attempt=1, outcome="veto", error=verdict)
                self._log_action(ctx, step, "GOTO", length, before, None, vetoed=True)
                return self._refused(ctx, option, memory, verdict), 1, False
            result = world.motion.go_to(x, y, obstacle_stop_m=self.cfg.obstacle_stop_m)
            if result.collided:
                self._log_action(ctx, step, "GOTO", length, before, result)
                return f"collided with {result.collision_with or 'an obstacle'}", 0, True
            if result.veto is not None:
                # The guarded layer refused this leg: the robot did not move. Near the landmark that is as
                # close as it may safely get (the goal point hugs the object); elsewhere the map learns
                # what blocked it and the same choice plans around it.
                lidar_map.integrate(self._pose(ctx), ctx.world.lidar.scan())
                self._log_action(ctx, step, "GOTO", length, before, result, vetoed=True)
                return self._refused(ctx, option, memory, result.veto), 1, False
            came = self._look(ctx, memory)
            # Exploring stops for what the task names (relevance order), or for anything new (neutral order,
            # where nothing is matched against the task): the model then decides with the new information.
            if option.kind == "frontier" and (came & memory.wanted or (came and not memory.wanted)):
                self._log_action(ctx, step, "GOTO", length, before, result)
                return "stopped exploring: new objects in view", 0, False
        if option.face is not None:
            pose = self._pose(ctx)
            turn = math.remainder(math.atan2(option.face[1] - pose.y, option.face[0] - pose.x) - pose.yaw, math.tau)
            world.motion.rotate(turn)
        if option.landmark_id is not None:
            memory.visited.add(option.landmark_id)
        if option.kind == "frontier" and option.goal is not None:
            memory.explored.append(option.goal)
        after = self._pose(ctx)
        ctx.log.event(
            "action",
            step=step,
            command="GOTO",
            parameters=round(before.distance_to(after.x, after.y), 3),
            option=option.text,
            pose_before=before.as_list(),
            pose_after=after.as_list(),
            collided=False,
        )
        if option.goal is not None and after.distance_to(*option.goal) > self.cfg.arrived_m:
            short = after.distance_to(*option.goal)
            return f"stopped {short:.1f} m short ({option.goal_name})", 0, False
        return f"reached {option.goal_name}", 0, False

    def _refused(self, ctx: EpisodeContext, option: Option, memory: Memory, reason: str) -> str:
        """What a vetoed leg means for the menu, as the result line says it.

        Near the landmark the refused spot is as close as the robot may safely get (its goal point hugs
        the object): it counts as arrival. Elsewhere the next plan avoids what the LiDAR saw; a landmark
        refused twice from the same spot is dropped from the menu, since the detour did not help.
        """
        here = self._pose(ctx)
        landmark = option.landmark_id
        near = option.face is not None and here.distance_to(*option.face) <= self.cfg.stop_within_m
        if landmark is not None and near:
            memory.closest[landmark] = (here.x, here.y)
            memory.visited.add(landmark)
            return f"as close to {option.goal_name} as is safe"
        if landmark is not None:
            again = memory.refused.get(landmark)
            if again is not None and here.distance_to(*again) <= 0.1:
                memory.unreachable.add(landmark)
            memory.refused[landmark] = (here.x, here.y)
        # The model is told that retrying is meaningful: the next plan avoids what blocked this one.
        return f"safety stop ({reason}); obstacle mapped, same choice detours"

    def _plan(self, grid: OccupancyGrid, start: Pose2D, goal: tuple[float, float]) -> list[tuple[float, float]] | None:
        """A* legs from the robot to the goal, no longer than `leg_max_m` each.

        A robot standing inside the inflation (beside a wall) first steps out to the nearest free cell:
        a long leg along the wall from there would graze it, and the veto would refuse it every time.
        """
        from llmnav.mapping.grid import nearest_free_cell
        from llmnav.mapping.paths import SNAP_M, plan_path

        first: list[tuple[float, float]] = []
        origin = (start.x, start.y)
        if not grid.is_free(*origin):
            cell = nearest_free_cell(grid.blocked, grid.geometry, start.x, start.y, SNAP_M)
            if cell is None:
                return None
            origin = grid.geometry.cell_to_world(*cell)
            first = [origin]
        path = plan_path(grid, origin, goal)
        if path is None:
            return None
        legs: list[tuple[float, float]] = list(first)
        previous = origin
        for point in path[1:]:
            span = math.dist(previous, point)
            pieces = max(1, math.ceil(span / self.cfg.leg_max_m))
            for k in range(1, pieces + 1):
                legs.append(
                    (
                        previous[0] + (point[0] - previous[0]) * k / pieces,
                        previous[1] + (point[1] - previous[1]) * k / pieces,
                    )
                )
            previous = point
        return legs

    def _veto(self, ctx: EpisodeContext, lidar_map: LidarMap, length: float) -> str | None:
        """The safety veto on a straight leg ahead; the reason when blocked."""
        from llmnav.guard.veto import check_motion

        scan = ctx.world.lidar.scan()
        # What blocked this leg goes into the map, so the next plan can route around it.
        lidar_map.integrate(self._pose(ctx), scan)
        verdict = check_motion(
            length,
            scan,
            robot_width_m=ctx.world.robot.spec.width_m,
            margin_m=self.cfg.veto_margin_m,
            stop_margin_m=self.cfg.veto_stop_margin_m,
        )
        return None if verdict.allowed else (verdict.reason or "blocked")

    def _look(self, ctx: EpisodeContext, memory: Memory) -> set[str]:
        """Run the detector; the landmarks the planner did not know that came into view."""
        return self._remember(ctx, memory, self._pose(ctx), ctx.world.detector.detect())

    @staticmethod
    def _pose(ctx: EpisodeContext) -> Pose2D:
        """Where the planner believes the robot is: odometry when sensed, else the true pose."""
        return ctx.world.robot.odom() if ctx.information == "sensed" else ctx.world.robot.pose()

    @staticmethod
    def _log_action(
        ctx: EpisodeContext,
        step: int,
        command: str,
        parameter: float,
        before: Pose2D,
        result: MotionResult | None,
        *,
        vetoed: bool = False,
    ) -> None:
        after = HybridPlanner._pose(ctx)
        fields: dict[str, Any] = {
            "step": step,
            "command": command,
            "parameters": round(parameter, 3),
            "pose_before": before.as_list(),
            "pose_after": after.as_list(),
            "collided": bool(result and result.collided),
            "collision_with": result.collision_with if result else None,
        }
        if vetoed:
            fields["vetoed"] = True
        ctx.log.event("action", **fields)


def _with_seen_obstacles(grid: OccupancyGrid, lidar_map: LidarMap, near_known: Any, depth_m: float) -> OccupancyGrid:
    """The grid plus the LiDAR hits away from every known solid (`near_known`), inflated alike.

    The extra `depth_m` [m] stands for the obstacle's back, which the LiDAR has not seen.
    """
    from dataclasses import replace

    from llmnav.mapping.grid import inflate

    unexpected = lidar_map.occupied & ~near_known
    if not unexpected.any():
        return grid
    return replace(
        grid,
        occupied=grid.occupied | unexpected,
        blocked=grid.blocked | inflate(unexpected, grid.inflation_m + depth_m, grid.geometry.resolution),
    )


def _sensed_grid(lidar_map: LidarMap, scenario: Scenario, inflation_m: float) -> OccupancyGrid:
    """A planning grid from the robot's own LiDAR map.

    Occupied and unknown cells (and the world's extent) are inflated by `inflation_m`, as the frontier
    baseline treats them.
    """
    from llmnav.mapping.grid import OccupancyGrid, inflate, near_bounds

    geometry = lidar_map.geometry
    blocked = inflate(lidar_map.occupied | lidar_map.unknown, inflation_m, geometry.resolution)
    blocked |= near_bounds(geometry, scenario.bounds, inflation_m)
    return OccupancyGrid(geometry, lidar_map.occupied, blocked, inflation_m)


def _estimate(pose: Pose2D, bearing_deg: float, distance_m: float) -> tuple[float, float]:
    """World position [m] of something seen at a bearing and distance from a pose."""
    heading = pose.yaw + math.radians(bearing_deg)
    return (pose.x + distance_m * math.cos(heading), pose.y + distance_m * math.sin(heading))


# Eight 45° sectors of bearing, counter-clockwise from straight ahead.
# The menu's direction words, counter-clockwise from ahead in 45 deg steps.
SECTORS = ("ahead", "front-left", "left", "back-left", "behind", "back-right", "right", "front-right")


def _where(pose: Pose2D, point: tuple[float, float]) -> str:
    """'3 m front-left' from the robot's point of view.

    Coarse on purpose: the navigation stack does the driving, so the model only needs to tell options
    apart, and every digit is a token of its own (whole metres; one decimal below 1 m).
    """
    bearing = math.degrees(pose.bearing_to(*point))
    sector = SECTORS[round(bearing / 45.0) % 8]
    distance = pose.distance_to(*point)
    return f"{distance:.1f} m {sector}" if distance < 0.95 else f"{distance:.0f} m {sector}"
