"""Saying so where a command's input leaves nothing worth scoring, rather than scoring it in
silence."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer

__all__ = [
    "MOST_BEAMS_UNKNOWN",
    "nothing_scored",
    "read_scorable",
    "refuse_too_short",
    "refuse_without_returns",
    "warn_nothing_scored",
    "warn_pose_jumps",
    "warn_unknown_beams",
]

#: Over this share of a recording's beams unknown, its maps are mostly blank: warned of. A real
#: scanner loses a few percent (glass, sky, its own frame); half is a broken driver or topic.
MOST_BEAMS_UNKNOWN = 0.5


def warn_unknown_beams(path: str | Path, recording: Any) -> None:
    """One line on stderr where more than :data:`MOST_BEAMS_UNKNOWN` of ``recording``'s beams
    are unknown."""
    from lidarflow.data.info import unknown_share

    share = unknown_share(recording)
    if share > MOST_BEAMS_UNKNOWN:
        typer.echo(
            f"warning: {Path(path).name}: {share:.0%} of its beams are invalid (NaN, -inf, 0 or "
            "under range_min): its maps are mostly blank (`lidarflow info` counts them)",
            err=True,
        )


def warn_pose_jumps(path: str | Path, recording: Any) -> None:
    """One line on stderr where ``recording``'s poses jump further between two scans than a
    robot drives."""
    from lidarflow.motion.odometry import MAX_SPEED, pose_jumps

    jumps = pose_jumps(recording.poses, recording.stamps_ns)
    if jumps:
        frame, metres = jumps[0]
        times = "once" if len(jumps) == 1 else f"{len(jumps)} times"
        typer.echo(
            f"warning: {Path(path).name}: its poses jump {times} faster than {MAX_SPEED:g} m/s "
            f"between scans (first {metres:g} m before frame {frame}): odometry glitches, "
            "which misplace those frames in the world frame the mover region is counted in",
            err=True,
        )


def refuse_too_short(name: str, recording: Any, warmup: int, horizon: int) -> None:
    """Refuse a recording too short to score ``horizon`` frames ahead after ``warmup``,
    naming it."""
    from lidarflow.data.gaps import frames_after_gaps
    from lidarflow.evaluate.horizon import scored_frames
    from lidarflow.evaluate.stream import check_length

    gaps = frames_after_gaps(recording.stamps_ns)
    check_length(len(recording), warmup, gaps, name)
    if horizon > 1:
        scored_frames(len(recording), horizon, warmup, gaps, name)


def refuse_without_returns(path: str | Path, recording: Any, what: str) -> None:
    """A :class:`~lidarflow.errors.RecordingError` where not one beam of ``recording`` is a
    return, so there is nothing to ``what`` (a verb: "predict on", "convert")."""
    from lidarflow.data.info import return_share
    from lidarflow.errors import RecordingError

    if return_share(recording) == 0:
        raise RecordingError(
            f"{path}: none of its {len(recording)} scans has a return (every range NaN, inf, 0 "
            f"or outside range_min..range_max), so nothing to {what}; is it the scanner's topic? "
            "(`lidarflow info` counts its beams)"
        )


def nothing_scored(entry: dict[str, Any]) -> bool:
    """Whether a recording's report ``entry`` scored nothing: no frame, or no occupied cell in
    any scored target frame."""
    return not entry.get("frames_evaluated") or "f1" in entry.get("undefined", [])


def warn_nothing_scored(entry: dict[str, Any]) -> None:
    """One line on stderr where ``entry`` (a recording's report) scored nothing."""
    if nothing_scored(entry):
        typer.echo(
            f"warning: {Path(entry['path']).name}: nothing was scored (no occupied cell in any "
            f"of its {entry.get('frames_evaluated', 0)} scored frames): its scores say nothing",
            err=True,
        )


def read_scorable(
    path: Path, topic: str | None, odom_topic: str | None, warmup: int, horizon: int,
    ego_oracle: bool,
) -> Any:
    """The recording at ``path``, refused at once where it cannot be scored (too short;
    ``--ego-oracle`` without poses) and warned of where its beams or poses are suspect."""
    from lidarflow.cli.app import load_input
    from lidarflow.errors import RecordingError

    recording = load_input(path, topic, odom_topic)
    refuse_too_short(str(path), recording, warmup, horizon)
    if ego_oracle and not recording.has_poses:  # the oracle's true poses are the recording's
        raise RecordingError(
            f"{path}: --ego-oracle tells models the true next pose, and this recording has "
            "no poses (no odometry; --odom-topic names its topic); drop --ego-oracle"
        )
    warn_unknown_beams(path, recording)
    warn_pose_jumps(path, recording)
    return recording
