"""The `Text` space of the task, readable through `AsyncVectorEnv`'s shared memory.

Gymnasium reads a `Text` out of shared memory once, when the vector environment is built, as a tuple of
strings, while its workers write every later observation into the buffer: with `shared_memory=True` (the
default of `make_vec(..., vectorization_mode="async")`) the task would stay the empty buffer's text, 512
spaces. `TaskText` reads the buffer whenever the observation is copied or indexed instead.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, overload

import numpy as np
from gymnasium import spaces
from gymnasium.vector.utils import read_from_shared_memory

from llmnav.errors import BadInputError


class NoArrayShape:
    """The shape of a text field: None to Gymnasium; unpacking it as an array shape raises why it cannot be."""

    def __init__(self, message: str) -> None:
        self.message = message

    def __iter__(self) -> Iterator[int]:
        raise BadInputError(self.message)

    def __len__(self) -> int:
        raise BadInputError(self.message)

    def __bool__(self) -> bool:
        return False

    def __eq__(self, other: object) -> bool:
        return other is None or isinstance(other, NoArrayShape)

    def __hash__(self) -> int:
        return hash(None)

    def __repr__(self) -> str:
        return "None"


class TaskText(spaces.Text):
    """A `Text` space whose vectorised shared-memory reading follows the buffer (see the module docstring).

    `array_id` names the registered id with array-only observations, for the error `shape` gives.
    """

    array_id: str | None = None

    @property
    def shape(self) -> Any:
        """No array shape: a `NoArrayShape` that says which id or wrapper to use instead."""
        instead = f"{self.array_id} (array-only observations)" if self.array_id else "an llmnav/*-Flat-v0 id"
        return NoArrayShape(
            "the observation field 'task' is text, which has no array shape for Stable-Baselines3's (or any "
            f"array-only learner's) buffers: use {instead}, or llmnav.gym.make_sb3(id)"
        )


class LiveTexts(Sequence[str]):
    """The n strings in a shared `Text` buffer, decoded when read; a deep copy is a plain tuple."""

    def __init__(self, space: spaces.Text, shared_memory: Any, n: int) -> None:
        self._space = space
        self._codes = np.frombuffer(shared_memory.get_obj(), dtype=np.int32).reshape((n, space.max_length))

    def _decode(self, row: np.ndarray) -> str:
        chars, size = self._space.character_list, len(self._space.character_set)
        return "".join(chars[c] for c in row if c < size)  # `size` pads past the end of the text

    @overload
    def __getitem__(self, index: int) -> str: ...
    @overload
    def __getitem__(self, index: slice) -> tuple[str, ...]: ...
    def __getitem__(self, index: int | slice) -> str | tuple[str, ...]:
        if isinstance(index, slice):
            return tuple(self._decode(row) for row in self._codes[index])
        return self._decode(self._codes[index])

    def __len__(self) -> int:
        return len(self._codes)

    def __iter__(self) -> Iterator[str]:
        return (self._decode(row) for row in self._codes)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and tuple(self) == tuple(other)

    def __hash__(self) -> int:
        return hash(tuple(self))

    def __repr__(self) -> str:
        return repr(tuple(self))

    def __deepcopy__(self, memo: dict[int, Any]) -> tuple[str, ...]:
        return tuple(self)


@read_from_shared_memory.register(TaskText)
def _read_live(space: TaskText, shared_memory: Any, n: int = 1) -> LiveTexts:
    return LiveTexts(space, shared_memory, n)
