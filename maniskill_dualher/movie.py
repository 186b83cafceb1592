"""State movies: one evaluated episode drawn from the simulator's state with matplotlib, no render device.

``evaluate --movie FILE`` (.gif or .mp4) calls :func:`draw_movie` on an episode that ``evaluate._episode``
traced: the TCP and goal paths seen from above (x-y) and the side (x-z) with the goal tolerance, the distance
to the goal over time against the tolerance, and the hinge angle (CloseBox, CloseMicrowave) or the per-axis
goal error (ReachTarget). 800x600 px at 10 frames/s, text of 10-13 pt: readable in a README at its own size.
"""
from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import numpy as np

from .cmdline import missing_package
from .config import ConfigError

MOVIE_SUFFIXES = (".gif", ".mp4")
# text sizes in points at dpi 100: a 10-pt tick label is ~14 px high in the 800x600 frame
FS_TITLE, FS_LABEL, FS_TICK, FS_SMALL = 13, 11, 10, 10


def task_info(env_id: str) -> dict:
    """What the movie needs to know of a task: goal tolerance, hinge (name, success angle) or none."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    from .tasks.hinged import HingedPanelEnv
    cls = REGISTERED_ENVS[env_id].cls
    hinged = issubclass(cls, HingedPanelEnv)
    return {"env_id": env_id, "tolerance": float(cls.goal_tolerance), "hinged": hinged,
            "angle_name": cls.ANGLE_INFO_KEY.replace("_", " ") if hinged else None,
            "success_angle": float(cls.SUCCESS_ANGLE) if hinged else None}


def draw_movie(ep: dict, info: dict, path, title_source=None, fps: int = 10,
               max_frames: int = 80, dpi: int = 100) -> Path:
    """A small movie (.gif or .mp4) of one traced episode (``_episode(..., trace=True)``): four panels drawn
    from the flat observations (slots in tasks/common.py): x-y and x-z paths of the TCP and the achieved goal
    with the desired goal and its tolerance circle, distance to goal vs step with the tolerance line, and the
    hinge angle (hinged tasks) or per-axis goal error (ReachTarget)."""
    need = missing_package("matplotlib", "--movie draws with")
    if need:
        raise ConfigError(need)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle
    from .tasks.common import GOAL_DIM, OBS_DIM, OBS_SLICES

    path = Path(path)
    flats = ep["flats"]
    T = flats.shape[0] - 1
    tcp = flats[:, OBS_SLICES["tcp_pose"]][:, :3]
    ag = flats[:, OBS_DIM:OBS_DIM + GOAL_DIM]
    dg = flats[:, OBS_DIM + GOAL_DIM:OBS_DIM + 2 * GOAL_DIM]
    dist = np.linalg.norm(ag - dg, axis=-1)
    angle = flats[:, OBS_SLICES["joint_qpos"]][:, 0]
    distract = flats[0, OBS_SLICES["distractor_pos"]].reshape(2, 3)
    tol = info["tolerance"]
    succ_step = ep.get("first_success_step")

    fig, axes = plt.subplots(2, 2, figsize=(8.0, 6.0), dpi=dpi)
    (ax_xy, ax_xz), (ax_d, ax_4) = axes
    pts = np.concatenate([tcp, ag, dg] + ([] if info["hinged"] else [distract]), 0)
    lo, hi = pts.min(0) - 0.06, pts.max(0) + 0.06
    views = [(ax_xy, 0, 1, "top view", "x (m)", "y (m)"), (ax_xz, 0, 2, "side view", "x (m)", "z (m)")]
    artists = []
    for ax, i, j, name, xl, yl in views:
        ax.set_title(name, fontsize=FS_TITLE)
        ax.set_xlabel(xl, fontsize=FS_LABEL, labelpad=1)
        ax.set_ylabel(yl, fontsize=FS_LABEL, labelpad=1)
        ax.tick_params(labelsize=FS_TICK)
        ax.set_xlim(lo[i], hi[i])
        ax.set_ylim(lo[j] if j < 2 else max(lo[j], -0.02), hi[j])
        ax.set_aspect("equal", adjustable="box")
        ax.add_patch(Circle((dg[0, i], dg[0, j]), tol, fill=False, ls="--", color="tab:green", lw=1.5))
        ax.plot([dg[0, i]], [dg[0, j]], "*", color="tab:green", ms=14, label="desired goal")
        if not info["hinged"] and np.abs(distract).sum() > 0:
            ax.plot(distract[:, i], distract[:, j], "o", color="0.6", ms=8, label="distractors")
        (tcp_path,) = ax.plot([], [], "-", color="tab:blue", lw=1.5)
        (tcp_now,) = ax.plot([], [], "o", color="tab:blue", ms=8, label="TCP")
        if info["hinged"]:
            (ag_path,) = ax.plot([], [], "-", color="tab:orange", lw=1.5)
            (ag_now,) = ax.plot([], [], "s", color="tab:orange", ms=8, label="panel free edge")
        else:
            ag_path = ag_now = None
        artists.append((i, j, tcp_path, tcp_now, ag_path, ag_now))
        if j == 2:
            ax.axhline(0.0, color="0.5", lw=0.8)  # table top
    # one row under the title, outside the views: inside, the narrow equal-aspect top view had it over ticks and points
    fig.legend(*ax_xy.get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.5, 0.955), ncol=3,
               fontsize=FS_SMALL, frameon=False, handletextpad=0.3, columnspacing=1.5)

    steps = np.arange(T + 1)
    ax_d.set_title("distance to goal", fontsize=FS_TITLE)
    ax_d.axhline(tol, ls="--", color="tab:green", lw=1.5)
    ax_d.text(0.98, tol, "tolerance", fontsize=FS_SMALL, va="bottom", ha="right", color="tab:green",
              transform=ax_d.get_yaxis_transform())
    ax_d.set_xlim(0, max(T, 1))
    ax_d.set_ylim(0, max(float(dist.max()), tol) * 1.1)
    ax_d.set_xlabel("step", fontsize=FS_LABEL, labelpad=1)
    ax_d.set_ylabel("m", fontsize=FS_LABEL, labelpad=1)
    ax_d.tick_params(labelsize=FS_TICK)
    (d_line,) = ax_d.plot([], [], "-", color="tab:red", lw=2)
    ax_4.set_xlim(0, max(T, 1))
    ax_4.set_xlabel("step", fontsize=FS_LABEL, labelpad=1)
    ax_4.tick_params(labelsize=FS_TICK)
    if info["hinged"]:
        ax_4.set_title(info["angle_name"], fontsize=FS_TITLE)
        ax_4.set_ylabel("rad", fontsize=FS_LABEL, labelpad=1)
        ax_4.axhline(info["success_angle"], ls="--", color="tab:green", lw=1.5)
        ax_4.text(0.98, info["success_angle"], "success below", fontsize=FS_SMALL, va="bottom", ha="right",
                  color="tab:green", transform=ax_4.get_yaxis_transform())
        ax_4.set_ylim(min(0.0, float(angle.min())) - 0.02, max(float(angle.max()), info["success_angle"]) * 1.1)
        lines4 = [ax_4.plot([], [], "-", color="tab:orange", lw=2)[0]]
        series4 = [angle]
    else:
        err = np.abs(ag - dg)
        ax_4.set_title("goal error per axis", fontsize=FS_TITLE)
        ax_4.set_ylabel("m", fontsize=FS_LABEL, labelpad=1)
        ax_4.set_ylim(0, max(float(err.max()), tol) * 1.1)
        lines4 = [ax_4.plot([], [], "-", color=c, lw=1.5, label=n)[0]
                  for c, n in zip(("tab:red", "tab:green", "tab:blue"), "xyz")]
        ax_4.legend(fontsize=FS_SMALL, loc="upper right", framealpha=0.6)
        series4 = [err[:, 0], err[:, 1], err[:, 2]]
    src = ""
    if title_source is not None and title_source.env_id != info["env_id"]:
        src = f" (policy from {title_source.env_id}, zero-shot)"
    title = fig.suptitle("", fontsize=FS_TITLE)
    fig.tight_layout(rect=(0, 0, 1, 0.91), pad=0.4, h_pad=0.6, w_pad=0.6)

    frames_at = np.unique(np.linspace(0, T, min(T + 1, max_frames)).round().astype(int))
    frames = []
    for f in frames_at:
        for i, j, tcp_path, tcp_now, ag_path, ag_now in artists:
            tcp_path.set_data(tcp[:f + 1, i], tcp[:f + 1, j])
            tcp_now.set_data([tcp[f, i]], [tcp[f, j]])
            if ag_path is not None:
                ag_path.set_data(ag[:f + 1, i], ag[:f + 1, j])
                ag_now.set_data([ag[f, i]], [ag[f, j]])
        d_line.set_data(steps[:f + 1], dist[:f + 1])
        for line, ser in zip(lines4, series4):
            line.set_data(steps[:f + 1], ser[:f + 1])
        status = "success" if (succ_step is not None and f >= succ_step) else ""
        title.set_text(f"{info['env_id']}{src}, seed {ep['seed']}: step {f}/{T}  {status}")
        title.set_color("tab:green" if status else "black")
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    _write_frames(frames, path, fps)
    return path


def _write_frames(frames: List[np.ndarray], path: Path, fps: int) -> None:
    """GIF through Pillow (adaptive palettes, the last frame held 1.5 s) or MP4 through imageio-ffmpeg."""
    import os

    from .fileio import atomic_write_with
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        from PIL import Image
        ims = [Image.fromarray(f).quantize(colors=48, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
               for f in frames]
        durations = [int(1000 / fps)] * len(ims)
        durations[-1] = 1500
        atomic_write_with(path, lambda tmp: ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:],
                                                         duration=durations, loop=0, optimize=True, disposal=1))
    else:
        import imageio.v2 as imageio

        tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.mp4")  # ffmpeg picks the format by suffix
        try:
            w = imageio.get_writer(str(tmp), format="FFMPEG", fps=fps, codec="libx264", quality=6,
                                   macro_block_size=16, pixelformat="yuv420p")
            try:
                for f in frames + [frames[-1]] * fps:  # hold the last frame a second
                    w.append_data(f)
            finally:
                w.close()
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()
