"""Record pointer episodes as MCAP files, one episode per file.

Channels (JSON, named jsonschema schemas so Foxglove shows them):

- ``/pointer/command`` (action), schema ``slearn.pointer.Command``: ``{"command": "R"}``;
- ``/pointer/position`` (observation), ``slearn.pointer.Position``: ``{"position": 17}``,
  the label the sensor reports;
- ``/pointer/angle`` (ground truth, not learned by default), ``slearn.pointer.Angle``:
  ``{"angle_deg": 163.2}``.

Log times: trial ``i`` issues its command at ``i * 100 ms`` and reads the resulting position
and angle at ``i * 100 ms + 50 ms``; the initial position and angle are at 0. A metadata
record ``slearn.pointer`` holds the condition, seed, every parameter and the slearn version.
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from pathlib import Path

from slearn import __version__
from slearn.errors import InputError
from slearn.recorders.mcap_episode import EpisodeWriter
from slearn.recorders.pointer import (
    COMMAND_CHANNEL,
    COMMAND_NAMES,
    N_BINS,
    POSITION_CHANNEL,
    PointerConfig,
    PointerRun,
    simulate,
)

ANGLE_CHANNEL = "/pointer/angle"
METADATA_NAME = "slearn.pointer"
TRIAL_NS = 100_000_000
SENSE_DELAY_NS = 50_000_000

COMMAND_SCHEMA = {
    "title": "slearn.pointer.Command",
    "description": "The command issued to the rotary pointer (R: +10 deg, L: -10 deg).",
    "type": "object",
    "properties": {"command": {"type": "string", "enum": list(COMMAND_NAMES)}},
    "required": ["command"],
}
POSITION_SCHEMA = {
    "title": "slearn.pointer.Position",
    "description": "The 10-degree bin the position sensor reports (label k covers "
                   "[10(k-1), 10k) degrees).",
    "type": "object",
    "properties": {"position": {"type": "integer", "minimum": 1, "maximum": N_BINS}},
    "required": ["position"],
}
ANGLE_SCHEMA = {
    "title": "slearn.pointer.Angle",
    "description": "Ground-truth pointer angle in degrees, [0, 360).",
    "type": "object",
    "properties": {"angle_deg": {"type": "number"}},
    "required": ["angle_deg"],
}


@dataclass(frozen=True)
class RecordSummary:
    """What one recording wrote."""

    path: str
    condition: str
    seed: int
    trials: int
    messages: dict[str, int]
    size_bytes: int

    def to_dict(self) -> dict:
        """A JSON-ready dict."""
        return asdict(self)


def record_pointer(config: PointerConfig, path: str | os.PathLike, *,
                   overwrite: bool = False) -> RecordSummary:
    """Simulate one pointer episode and write it to ``path`` (see :func:`write_pointer_mcap`)."""
    return write_pointer_mcap(simulate(config), path, overwrite=overwrite)


def write_pointer_mcap(run: PointerRun, path: str | os.PathLike, *,
                       overwrite: bool = False) -> RecordSummary:
    """Write ``run`` as one MCAP episode at ``path``, atomically.

    Raises:
        InputError: ``path`` exists and ``overwrite`` is false, or its folder is missing, or
            the run does not have the logs' 36 bins.
    """
    if run.config.bins != N_BINS:
        raise InputError(f"pointer logs have {N_BINS} bins, not {run.config.bins}: simulate "
                         "other bin counts in memory (slearn.recorders.pointer.simulate)")
    with EpisodeWriter(path, overwrite=overwrite) as out:
        out.add_metadata(METADATA_NAME, pointer_metadata(run))
        command = out.register_channel(COMMAND_CHANNEL, COMMAND_SCHEMA["title"], COMMAND_SCHEMA,
                                       {"role": "action"})
        position = out.register_channel(POSITION_CHANNEL, POSITION_SCHEMA["title"],
                                        POSITION_SCHEMA, {"role": "observation"})
        angle = out.register_channel(ANGLE_CHANNEL, ANGLE_SCHEMA["title"], ANGLE_SCHEMA,
                                     {"role": "ground_truth"})
        _write_trials(out, run, command, position, angle)
    trials = len(run)
    counts = {COMMAND_CHANNEL: trials, POSITION_CHANNEL: trials + 1, ANGLE_CHANNEL: trials + 1}
    return RecordSummary(str(path), run.config.condition, run.config.seed, trials, counts,
                         Path(path).stat().st_size)


def pointer_metadata(run: PointerRun) -> dict[str, str]:
    """The ``slearn.pointer`` metadata record of a run."""
    metadata = run.config.parameters()
    metadata.update(simulator="slearn.recorders.pointer", slearn_version=__version__,
                    bins=str(N_BINS), trial_ns=str(TRIAL_NS), sense_delay_ns=str(SENSE_DELAY_NS))
    if "scramble" in run.config.effects:
        metadata["sensor_labels_after_switch"] = " ".join(map(str, run.sensor_labels.tolist()))
    return metadata


def _write_trials(out: EpisodeWriter, run: PointerRun, command: int, position: int,
                  angle: int) -> None:
    # Payloads are cached: commands and positions take few values (about 3x faster).
    command_data = [b'{"command":"%s"}' % name.encode() for name in COMMAND_NAMES]
    position_data = [b'{"position":%d}' % label for label in range(N_BINS + 1)]
    labels = run.positions.tolist()
    angles = [b'{"angle_deg":%r}' % value for value in run.angles.tolist()]
    out.write_encoded(position, 0, position_data[labels[0]])
    out.write_encoded(angle, 0, angles[0])
    for i, name in enumerate(run.commands.tolist()):
        issued_ns = i * TRIAL_NS
        out.write_encoded(command, issued_ns, command_data[name])
        out.write_encoded(position, issued_ns + SENSE_DELAY_NS, position_data[labels[i + 1]])
        out.write_encoded(angle, issued_ns + SENSE_DELAY_NS, angles[i + 1])
