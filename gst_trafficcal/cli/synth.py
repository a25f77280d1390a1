"""``trafficcal synth``: render a synthetic traffic video with exact ground truth."""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import InputError


@click.command(name="synth")
@click.option("--preset", "preset", metavar="NAME", help="Named scenario (see --list-presets).")
@click.option("--scenario", "scenario_file", type=click.Path(dir_okay=False, path_type=Path),
              help="Scenario YAML/JSON file (may name a preset as 'base').")
@click.option("--duration", type=float, default=None, help="Seconds of video (default: the scenario's).")
@click.option("--seed", type=click.IntRange(min=0), default=None,
              help="Random seed, a whole number from 0 (default: the scenario's).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), help="Output folder.")
@click.option("--list-presets", is_flag=True, help="Print the presets, one a line, and exit.")
@click.option("--no-progress", is_flag=True, help="Do not show the progress bar.")
def command(preset: str | None, scenario_file: Path | None, duration: float | None, seed: int | None,
            out_dir: Path | None, list_presets: bool, no_progress: bool) -> None:
    """Render a synthetic roadside-camera video with exact ground truth.

    Writes video.mp4, gt_data.pkl (BrnoCompSpeed structure), calibration.json, frames.jsonl (per-frame,
    per-vehicle ground truth), preview.png and scenario.json into --out.
    """
    from ..synth import scenario as sc

    if list_presets:
        for name, desc in sc.list_presets():
            click.echo(f"{name}  {desc}")
        return
    if (preset is None) == (scenario_file is None):
        raise InputError("give exactly one of --preset NAME or --scenario FILE")
    if out_dir is None:
        raise InputError("--out DIR is required")
    scen = sc.load_preset(preset) if preset is not None else sc.load_scenario(scenario_file)
    if duration is not None:
        scen.duration = duration
    if seed is not None:
        scen.seed = seed
    scen.validate(preset or str(scenario_file))

    from ..synth.generate import generate

    if no_progress:
        res = generate(scen, out_dir)
    else:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

        with Progress("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                      TimeRemainingColumn(), transient=False) as bar:
            task = bar.add_task(f"synth {scen.name}", total=None)

            def tick(i: int, n: int) -> None:
                bar.update(task, completed=i, total=n)

            res = generate(scen, out_dir, progress=tick)
    click.echo(f"{res.out_dir}: {res.frames} frames ({res.dropped} dropped), {res.vehicles} vehicles with "
               f"ground truth, calibration {res.calibration.id}")
