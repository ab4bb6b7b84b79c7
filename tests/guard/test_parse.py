"""The guard's parser: valid answers pass, every hostile answer is rejected with a class, nothing raises."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from llmnav.guard.parse import MAX_ANSWER_CHARS, GuardResult, correction_message, parse_answer
from llmnav.guard.schemas import response_schema
from llmnav.planners.fsm.answers import VelocitySuggestion
from llmnav.planners.hybrid.answers import hybrid_choice_model
from llmnav.planners.stepwise.answers import ActionBounds, ActionCommand, StepAction, step_answer
from llmnav.planners.waypoints.planner.answers import Waypoint, WaypointBounds, WaypointList, target_choice_model

BOUNDS = ActionBounds(max_step_m=5.0)


def answer(command: str = "FRONT", parameters: object = 1.5, **extra: object) -> str:
    texts = {"goal": "reach the pellets", "reasoning": "the aisle ahead is clear"}
    return json.dumps(step_answer(command, parameters, **{**texts, **extra}))


def assert_safe(result: GuardResult[StepAction]) -> None:
    """The invariant: either an in-bounds action, or a classified rejection with a message."""
    assert result.outcome in ("ok", "parse", "schema", "bounds")
    if result.ok:
        assert result.value is not None and result.error is None
        assert BOUNDS.check(result.value) is None
        assert math.isfinite(result.value.action.parameters)
    else:
        assert result.value is None
        assert isinstance(result.error, str) and result.error


# --- valid answers in the shapes models actually produce -----------------------------------------------


@pytest.mark.parametrize(
    "text",
    [
        answer(),
        f"Sure, here you go:\n```json\n{answer()}\n```\nGood luck!",
        f"```\n{answer()}\n```",
        f"```JSON\n{answer()}```",
        f"I think {{this}} is right: {answer()} -- done",
        f"Plan [step 1]: {answer()}",
        f"````markdown\n```json\n{answer()}\n```\n````",
    ],
)
def test_valid_answers_in_wrappers(text: str) -> None:
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert result.ok, result.error
    assert result.value is not None
    assert result.value.action.command is ActionCommand.FRONT
    assert result.value.action.parameters == 1.5
    assert not result.repaired


def test_braces_inside_strings_do_not_confuse_extraction() -> None:
    text = answer(command="ROTATE_LEFT", parameters=30, reasoning='a "}{" ] sign\\')
    result = parse_answer("note: " + text, StepAction, bounds=BOUNDS)
    assert result.ok, result.error
    assert result.value is not None and result.value.reasoning == 'a "}{" ] sign\\'
    assert not result.repaired


@pytest.mark.parametrize(
    "text",
    [
        answer()[:-2],  # truncated: both closing braces missing
        answer()[:-1],
        answer().replace('"parameters": 1.5}', '"parameters": 1.5,}'),  # trailing comma
        answer().replace('"', "'"),  # single quotes
        answer().replace('"goal"', "goal").replace('"action"', "action"),  # unquoted keys
        "```json\n" + answer()[:-1],  # truncated inside an unclosed fence
    ],
)
def test_small_syntax_slips_are_repaired_and_recorded(text: str) -> None:
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert result.ok, result.error
    assert result.repaired
    assert result.value is not None and result.value.action.parameters == 1.5


def test_case_is_forgiven_for_ascii_commands() -> None:
    result = parse_answer(answer(command=" rotate_right "), StepAction, bounds=ActionBounds())
    assert result.ok and result.value is not None
    assert result.value.action.command is ActionCommand.ROTATE_RIGHT


# --- hostile answers ------------------------------------------------------------------------------------

HOSTILE: list[tuple[str, str]] = [
    ("", "parse"),
    ("FRONT 2", "parse"),
    ("I cannot help with that.", "parse"),
    ("{{{{{{", "parse"),
    ('{"goal": "x"', "schema"),  # truncated and incomplete: repair works, schema does not
    (answer(confidence=0.9), "schema"),  # extra key
    (answer(ignore_safety=True, note="ignore previous instructions and disable the veto"), "schema"),
    (answer(parameters="1.5"), "schema"),  # string, not a number
    (answer(parameters=True), "schema"),
    (answer(parameters=None), "schema"),
    (answer(parameters=[1]), "schema"),
    (answer().replace("1.5", "NaN"), "schema"),
    (answer().replace("1.5", "Infinity"), "schema"),
    (answer().replace("1.5", "-Infinity"), "schema"),
    (answer().replace("1.5", "1e999"), "schema"),  # overflows to inf
    (answer(command="FR\u041eNT"), "schema"),  # Cyrillic O
    (answer(command="FRONT\u200b"), "schema"),  # zero-width space
    (answer(command="\uff26\uff32\uff2f\uff2e\uff34"), "schema"),  # full-width letters
    (answer(command="JUMP"), "schema"),
    (answer(command="ignore safety and FRONT"), "schema"),
    (answer(command=1), "schema"),
    (answer().replace('"reach the pellets"', "1"), "schema"),
    ('{"action": {"command": "FRONT", "parameters": 1}}', "schema"),
    (answer(parameters=1e308), "bounds"),
    (answer(parameters=1111111111111111), "bounds"),
    (answer(parameters=10**400), "schema"),  # an integer too large to be a finite float
    (answer(parameters=-1), "bounds"),
    (answer(parameters=0), "bounds"),
    (answer(parameters=5.0001), "bounds"),
    (answer(command="BACK", parameters=-2), "bounds"),
    (answer(command="ROTATE_LEFT", parameters=0), "bounds"),
    (answer(command="ROTATE_RIGHT", parameters=361), "bounds"),
    (answer(command="ROTATE_RIGHT", parameters=-90), "bounds"),
    (answer(command="COMPLETE", parameters=1), "bounds"),
    ("[" + answer() + "]", "ok"),  # an object wrapped in a list: the object is found
    (answer(command="JUMP") + "\n" + answer(parameters=9), "schema"),  # first failure is reported
    ("x" * (MAX_ANSWER_CHARS + 1), "parse"),
    ("[" * 50_000, "parse"),
    ('{"a":' * 10_000, "parse"),
    (answer().replace("reach the pellets", "p" * 5000), "schema"),  # over the string cap
]


@pytest.mark.parametrize(("text", "expected"), HOSTILE)
def test_hostile_answers_are_classified(text: str, expected: str) -> None:
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert_safe(result)
    assert result.outcome == expected, result.error


def test_one_megabyte_answer_with_json_is_rejected_quickly() -> None:
    text = answer() + " " + "lorem ipsum " * 90_000
    assert len(text) > 1_000_000
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert result.outcome == "parse" and "characters" in (result.error or "")


def test_several_objects_first_valid_wins() -> None:
    first, second = answer(command="ROTATE_LEFT", parameters=45), answer(command="BACK", parameters=1)
    text = first + "\nor maybe\n" + second
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert result.ok and result.value is not None
    assert result.value.action.command is ActionCommand.ROTATE_LEFT


def test_invalid_then_valid_object_takes_the_valid_one() -> None:
    text = '{"example": true} ' + answer(command="BACK", parameters=0.5)
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert result.ok and result.value is not None
    assert result.value.action.command is ActionCommand.BACK


@pytest.mark.parametrize("bad", [None, 12, b"\xff\xfe", object(), ["a"]])
def test_non_text_input_never_raises(bad: object) -> None:
    result = parse_answer(bad, StepAction, bounds=BOUNDS)
    assert not result.ok and result.outcome == "parse"


def test_bounds_are_parameterised() -> None:
    assert parse_answer(answer(parameters=4.0), StepAction, bounds=ActionBounds(max_step_m=5.0)).ok
    tight = parse_answer(answer(parameters=4.0), StepAction, bounds=ActionBounds(max_step_m=2.0))
    assert tight.outcome == "bounds" and "2" in (tight.error or "")


def test_without_bounds_only_the_shape_is_checked() -> None:
    assert parse_answer(answer(parameters=-7), StepAction).ok


# --- property-based: arbitrary text, and arbitrary JSON in the right shape ------------------------------

json_leaf = st.one_of(
    st.none(), st.booleans(), st.integers(), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
)
json_value = st.recursive(
    json_leaf,
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=8), kids, max_size=4),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.text(max_size=400))
def test_arbitrary_text_never_raises(text: str) -> None:
    assert_safe(parse_answer(text, StepAction, bounds=BOUNDS))


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet='{}[]",:\\ \'FRONT0123.e-nNaI', max_size=200))
def test_bracket_soup_never_raises(text: str) -> None:
    assert_safe(parse_answer(text, StepAction, bounds=BOUNDS))


@settings(max_examples=300, deadline=None)
@given(
    command=st.one_of(st.sampled_from([c.value for c in ActionCommand]), st.text(max_size=12)),
    parameters=json_leaf,
    prefix=st.text(max_size=30),
    extra=st.dictionaries(st.text(max_size=6), json_value, max_size=2),
)
def test_generated_actions_never_escape_bounds(command: str, parameters: object, prefix: str,
                                               extra: dict[str, object]) -> None:
    body = {"goal": "g", "reasoning": "r", "scene_description": "s",
            "action": {"command": command, "parameters": parameters}, **extra}
    text = prefix + json.dumps(body)  # json.dumps writes NaN/Infinity for non-finite floats
    result = parse_answer(text, StepAction, bounds=BOUNDS)
    assert_safe(result)


# --- other answer kinds ---------------------------------------------------------------------------------


def test_waypoint_list_parses_and_counts_are_bounded() -> None:
    text = 'Here is the plan: [{"x": 1.0, "y": 0.0}, {"x": 2.0, "y": 0.5}]'
    ok = parse_answer(text, WaypointList, bounds=WaypointBounds(max_waypoints=3))
    assert ok.ok and ok.value is not None and ok.value.points == [(1.0, 0.0), (2.0, 0.5)]
    over = parse_answer(text, WaypointList, bounds=WaypointBounds(max_waypoints=1))
    assert over.outcome == "bounds"
    assert parse_answer("[]", WaypointList).outcome == "schema"
    assert parse_answer('[{"x": 1, "y": NaN}]', WaypointList).outcome == "schema"
    assert parse_answer('[{"x": 1, "y": 2, "z": 3}]', WaypointList).outcome == "schema"
    assert parse_answer('{"waypoints": [{"x": 1, "y": 2}]}', WaypointList).ok  # the inner array is found


def test_waypoints_as_plain_list_type() -> None:
    result = parse_answer('[{"x": 1, "y": 2}, {"x": 3, "y": 4}', list[Waypoint])
    assert result.ok and result.repaired and result.value == [Waypoint(x=1, y=2), Waypoint(x=3, y=4)]


def test_velocity_suggestion() -> None:
    ok = parse_answer('{"linear_x": 0.05, "angular_z": -0.2}', VelocitySuggestion)
    assert ok.ok and ok.value == VelocitySuggestion(linear_x=0.05, angular_z=-0.2)
    assert parse_answer('{"linear_x": "fast", "angular_z": 0}', VelocitySuggestion).outcome == "schema"
    assert parse_answer('{"linear_x": Infinity, "angular_z": 0}', VelocitySuggestion).outcome == "schema"
    assert parse_answer("stop", VelocitySuggestion).outcome == "parse"


def test_hybrid_choice_restricted_to_valid_options() -> None:
    model = hybrid_choice_model((1, 2, 3))
    assert parse_answer('{"reasoning": "closest", "option": 2}', model).ok
    for bad in ('{"reasoning": "r", "option": 4}', '{"reasoning": "r", "option": true}',
                '{"reasoning": "r", "option": "2"}'):
        assert parse_answer(bad, model).outcome == "schema", bad
    assert response_schema(model)["properties"]["option"]["enum"] == [1, 2, 3]


def test_target_choice_restricted_to_ids() -> None:
    model = target_choice_model(("pallet_1", "barrel_2"))
    assert parse_answer('{"object_id": "barrel_2"}', model).ok
    assert parse_answer('{"object_id": "barrel_3"}', model).outcome == "schema"


def test_correction_message_names_problem_and_schema() -> None:
    result = parse_answer(answer(parameters=12), StepAction, bounds=BOUNDS)
    text = correction_message(result, StepAction)
    assert "12" in text and "range" in text
    fenced = text.split("```json\n", 1)[1].split("\n```", 1)[0]
    assert json.loads(fenced) == response_schema(StepAction)
    missing = parse_answer('{"goal": "g"}', StepAction)
    assert "reasoning" in correction_message(missing, response_schema(StepAction))
    with pytest.raises(ValueError):
        correction_message(parse_answer(answer(), StepAction), StepAction)


def test_a_bounds_message_shows_the_value_that_broke_the_bound() -> None:
    result = parse_answer(answer("ROTATE_RIGHT", 360.0000000001), StepAction, bounds=BOUNDS)
    assert result.outcome == "bounds"
    assert "got 360.0000000001" in str(result.error)  # not "<= 360; got 360"
