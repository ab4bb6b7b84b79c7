"""A live view of a drive over Foxglove's WebSocket protocol (foxglove-sdk), on 127.0.0.1 only.

Each run-log event is translated as the MCAP export translates it (`export.Translator`), and published on
the same topics with the same schemas while the robot drives: Foxglove (or any client of the
`foxglove.websocket.v1` protocol) connects to ws://127.0.0.1:PORT and subscribes. A failure to publish is
counted and never stops the run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from llmnav.errors import BadInputError
from llmnav.ros.export import ROS_TOPICS, Translator
from llmnav.ros.messages import JSON_TOPICS, RosMessages, json_schema
from llmnav.runs.runlog import dumps

HOST = "127.0.0.1"  # never another interface: the run's prompts and images are on these topics


def missing_dependency() -> str | None:
    """None when foxglove-sdk and the MCAP writer's libraries import, else the hint to install them."""
    try:
        # deferred: foxglove-sdk and rosbags are the optional 'ros' extra; this checks for them
        import foxglove  # noqa: F401
        import rosbags.typesys  # noqa: F401
    except ImportError as err:
        return f"--foxglove needs the 'ros' extra ({err.name} is missing): pip install 'llmnav[ros]'"
    return None


class LiveView:
    """A Foxglove WebSocket server publishing a run's topics; `on_event` takes each logged event."""

    def __init__(self, port: int, run_dir: Path) -> None:
        hint = missing_dependency()
        if hint is not None:
            raise BadInputError(hint)
        # deferred: foxglove-sdk is the optional 'ros' extra
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()  # this run's channels only, not the SDK's global ones
        try:
            self._server = foxglove.start_server(name="llmnav", host=HOST, port=port, context=self._context)
        except Exception as err:  # the SDK raises its own error types for a port in use
            raise BadInputError(f"--foxglove {port}: cannot listen on {HOST}:{port}: {err}") from None
        self.port = int(self._server.port)
        self._messages = RosMessages()
        self._translator = Translator(Path(run_dir), self._messages)
        self._channels: dict[str, Any] = {}
        self.failures = 0  # messages that could not be published

    @property
    def url(self) -> str:
        """Where a client connects."""
        return f"ws://{HOST}:{self.port}"

    def _channel(self, topic: str) -> Any:
        if topic not in self._channels:
            foxglove = self._foxglove
            if topic in ROS_TOPICS:
                msgtype = ROS_TOPICS[topic]
                schema = foxglove.Schema(
                    name=msgtype, encoding="ros2msg", data=self._messages.definition(msgtype).encode()
                )
                encoding = "cdr"
            else:
                title, properties = JSON_TOPICS[topic]
                schema = foxglove.Schema(
                    name=title, encoding="jsonschema", data=json.dumps(json_schema(title, properties)).encode()
                )
                encoding = "json"
            self._channels[topic] = foxglove.Channel(
                topic, schema=schema, message_encoding=encoding, context=self._context
            )
        return self._channels[topic]

    # the Sink protocol of export.Translator
    def ros(self, topic: str, t_sim: float, message: Any) -> None:
        """Publish one ROS 2 message (CDR)."""
        self._channel(topic).log(self._messages.serialize(message), log_time=round(t_sim * 1e9))

    def json(self, topic: str, t_sim: float, record: dict[str, Any]) -> None:
        """Publish one JSON message."""
        self._channel(topic).log(dumps(record).encode(), log_time=round(t_sim * 1e9))

    def on_event(self, event: dict[str, Any]) -> None:
        """Translate and publish one logged event (a RunLog listener)."""
        try:
            self._translator.feed(event, self)
        except Exception:  # a view must not end a drive: count it, the run log has the event anyway
            self.failures += 1

    def close(self) -> None:
        """Stop the server (clients are disconnected)."""
        self._server.stop()
