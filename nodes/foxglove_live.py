"""``btrun MISSION --foxglove [PORT]``: the run live in Foxglove, over its WebSocket protocol.

A :class:`FoxgloveTee` starts a Foxglove WebSocket server (the ``foxglove-sdk`` package's
``foxglove.start_server``, on loopback unless told otherwise) with one channel per
``run.mcap`` channel (:data:`nodes.mcap_schemas.CHANNELS`: same topic, schema and JSON
encoding). The ``run.mcap`` recorder (:mod:`nodes.mcap_log`) hands it every message it
writes, with the same log time, so Foxglove's live connection shows what the file will
hold: the 3D scene, the camera with its annotations, the plots. ``docs/foxglove-layout.json``
is a Foxglove layout for those panels.
"""

from __future__ import annotations

import json
from typing import Any

from nodes.mcap_schemas import CHANNELS

DEFAULT_PORT = 8765


class FoxgloveError(Exception):
    """The server cannot start (the package is missing, the port is in use)."""


class FoxgloveTee:
    """A Foxglove WebSocket server with ``run.mcap``'s channels; :meth:`log` publishes."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1", name: str = "btrun"):
        try:
            import foxglove
        except ImportError as exc:  # pragma: no cover - a declared dependency
            raise FoxgloveError(f"the foxglove-sdk package is not installed ({exc})") from None
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name=name, host=host, port=port, context=self.context
            )
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types
            raise FoxgloveError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.host, self.port = host, int(self.server.port)
        self.channels: dict[str, Any] = {}
        for topic, (schema, _) in CHANNELS.items():
            self.channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode()
                ),
                message_encoding="json",
                context=self.context,
            )

    def log(self, topic: str, log_time_ns: int, data: bytes) -> None:
        """Publish one JSON message of ``topic`` at ``log_time_ns`` (mission time)."""
        channel = self.channels.get(topic)
        if channel is not None:
            channel.log(data, log_time=log_time_ns)

    def close(self) -> None:
        """Stop the server (idempotent)."""
        server, self.server = getattr(self, "server", None), None
        if server is not None:
            server.stop()


def layout_json() -> str:
    """The Foxglove layout of ``docs/foxglove-layout.json`` (built with the SDK's
    ``foxglove.layouts``): the 3D scene following the drone, the camera with its detection
    boxes, position and battery plots, the log and the identification result."""
    from foxglove import layouts as fl

    def plot(title: str, fields: list[str]) -> Any:
        series = [fl.PlotSeries(value=f"/vehicle/telemetry.{f}", enabled=True) for f in fields]
        config = fl.PlotConfig(paths=series, show_legend=True, is_synced=True)
        return fl.PlotPanel(title=title, config=config)

    scene = fl.ThreeDeePanel(
        title="warehouse",
        config=fl.ThreeDeeConfig(
            follow_tf="base_link",
            follow_mode="follow-position",
            topics={
                "/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True),
                "/vehicle/pose": fl.BaseRendererPoseTopicSettings(visible=True),
            },
        ),
    )
    camera = fl.ImagePanel(
        title="camera",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(
                image_topic="/camera/image",
                annotations={"/camera/annotations": fl.ImageAnnotationSettings(visible=True)},
            )
        ),
    )
    log = fl.LogPanel(title="log", config=fl.LogConfig(topic_to_render="/log"))
    result = fl.RawMessagesPanel(
        title="identification", config=fl.RawMessagesConfig(topic_path="/result")
    )

    def split(direction: str, *items: tuple[float, Any]) -> Any:
        return fl.SplitContainer(
            direction=direction,  # type: ignore[arg-type]
            items=[fl.SplitItem(proportion=p, content=c) for p, c in items],
        )

    left = split("column", (3, scene), (2, camera))
    plots = split("column", (1, plot("position", ["x", "y", "z"])), (1, plot("battery", ["vbat"])))
    right = split("column", (2, plots), (1, log), (1, result))
    layout = fl.Layout(content=split("row", (3, left), (2, right)))
    return json.dumps(json.loads(layout.to_json()), indent=1)
