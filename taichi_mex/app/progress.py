"""The progress bar the command line hands to Simulation.run (the library prints nothing)."""

from __future__ import annotations


class ProgressBar:
    """tqdm over simulated seconds, with the particle count and the last step."""

    def __init__(self, t_start_s: float, t_end_s: float):
        from tqdm import tqdm

        self.bar = tqdm(total=max(t_end_s - t_start_s, 1e-12), unit="sim-s", unit_scale=False,
                        dynamic_ncols=True,
                        bar_format="{l_bar}{bar}| {n:.4g}/{total:.4g} sim-s [{elapsed}<{remaining}{postfix}]")
        self.steps = 0

    def update(self, t_s: float, dt_s: float, particles: int) -> None:
        # float sums of dt overshoot the total by an ulp: tqdm then warns
        self.bar.update(min(dt_s, max(self.bar.total - self.bar.n, 0.0)))
        self.steps += 1
        if self.steps % 50 == 0:
            self.bar.set_postfix(particles=particles, dt=f"{dt_s:.2e}", refresh=False)

    def close(self) -> None:
        self.bar.close()
