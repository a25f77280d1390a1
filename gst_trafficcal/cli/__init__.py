"""The ``trafficcal`` command line.

Each command lives in its own module of this package and is imported only when it is run
(so ``trafficcal --help`` stays fast). To add one, write ``gst_trafficcal/cli/<name>.py``
defining a click command called ``command`` and list it in ``COMMANDS``.
"""

from __future__ import annotations

import importlib
import sys

import click

from ..errors import TrafficcalError

# command name -> (module inside gst_trafficcal.cli, one-line help shown in `trafficcal --help`)
COMMANDS: dict[str, tuple[str, str]] = {
    "models": ("models", "Install and list detector models (ONNX) in the per-user cache."),
    "gst-env": ("gst_env", "Print the shell exports that let gst-launch-1.0 find our elements."),
    "eval": ("evaluate", "Score results/calibration against BrnoCompSpeed ground truth."),
    "calibrate": ("calibrate", "Fully automatic VP1/VP2 calibration of a traffic video (Diamond Space)."),
    "calibrate-manual": ("calibrate_manual",
                         "Calibration from road measurements (yours or a BrnoCompSpeed recording's)."),
    "synth": ("synth", "Render a synthetic traffic video with exact ground truth."),
    "demo": ("demo", "Run the main job on a built-in synthetic input and print the result."),
    "run": ("run", "Calibrate and measure every vehicle of a video in one pass (GStreamer elements), with outputs."),
    "fit-scale": ("fit_scale", "Fit the BBScale scale-correction regression on training scenes."),
    "report": ("report", "Write report.html from a run's vehicle events, calibration and optional ground truth."),
    "status": ("status", "What a run is doing (its status.json); a health check's exit code."),
}


class LazyGroup(click.Group):
    """A click group whose sub-commands are imported on first use."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(COMMANDS)

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name not in COMMANDS:
            return None
        module = importlib.import_module(f"{__name__}.{COMMANDS[name][0]}")
        return module.command

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows = [(name, COMMANDS[name][1]) for name in self.list_commands(ctx)]
        with formatter.section("Commands"):
            formatter.write_dl(rows)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="gst-trafficcal")
def cli() -> None:
    """gst-trafficcal: fully automatic traffic camera calibration and vehicle speed measurement.

    Every command has its own --help.
    """


def main(argv: list[str] | None = None) -> None:
    """Entry point: user errors become one line on stderr and exit code 2, never a traceback."""
    try:
        cli.main(args=argv, prog_name="trafficcal", standalone_mode=False)
    except click.exceptions.Abort:
        click.echo("Aborted.", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except TrafficcalError as exc:
        click.echo(f"trafficcal: error: {exc}", err=True)
        sys.exit(2)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
