"""Draw a generated warehouse with the ORCA robot driving it: the README's picture of ``CrowdNavWarehouse-v0``.

    python examples/warehouse_figure.py --out paper_results/warehouse/episode.png [--seed 1000003] [--time 8]

Left: the rendered frame at ``--time`` seconds (racks and walls grey, the robot's route dashed red, its trace
gold, pickers coloured, standing pickers hatched). Right: the whole episode over the layout (circles every 2 s).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

import sb3_crowdnav  # noqa: F401
from sb3_crowdnav import OrcaPolicy
from sb3_crowdnav.evaluation import plot_trajectories, run_episodes


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--seed", type=int, default=1_000_003)
    p.add_argument("--time", type=float, default=8.0, help="time of the rendered frame [s]")
    args = p.parse_args(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    env = gym.make("CrowdNavWarehouse-v0", render_mode="rgb_array")
    policy = OrcaPolicy.from_env(env, mapping="constrained")
    obs, _ = env.reset(seed=args.seed)
    frame = env.render()
    for _ in range(round(args.time / env.unwrapped.scene.time_step)):
        obs, _, terminated, truncated, _ = env.step(int(policy.predict(obs)[0]))
        frame = env.render()
        if terminated or truncated:
            break
    env.close()
    whole = args.out.with_name(args.out.stem + "_trajectory.png")
    record = run_episodes("orca-constrained", seeds=[args.seed], env_id="CrowdNavWarehouse-v0", keep_trajectories=True)[0]
    plot_trajectories({"ORCA robot": record}, whole, panel_size=5.0)
    images = [_crop(frame / 255.0), _crop(plt.imread(whole)[..., :3])]
    fig, axes = plt.subplots(1, 2, figsize=(12, 12 * max(i.shape[0] / i.shape[1] for i in images) / 2 + 0.2),
                             gridspec_kw={"width_ratios": [i.shape[1] / i.shape[0] for i in images]})
    for ax, image in zip(axes, images, strict=True):
        ax.imshow(image)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(args.out, dpi=90)
    whole.unlink()
    print(f"wrote {args.out}")


def _crop(image):
    """The image without its white margins."""
    content = (image < 0.97).any(axis=2)
    rows, cols = content.any(axis=1).nonzero()[0], content.any(axis=0).nonzero()[0]
    return image[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]


if __name__ == "__main__":
    main()
