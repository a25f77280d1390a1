"""``trafficcal gst-env``: print the shell exports that let gst-launch-1.0 find our elements."""

from __future__ import annotations

import click

from ..gst.env import gst_environment, require_plugin_loader, shell_exports


@click.command(name="gst-env")
@click.option("--plugin-dir", "plugin_dirs", multiple=True, type=click.Path(exists=True, file_okay=False),
              help="Extra GST_PLUGIN_PATH entry (a directory with a python/ subdirectory); repeatable.")
def command(plugin_dirs: tuple[str, ...]) -> None:
    """Print `export` lines for VIRTUAL_ENV, PATH, GST_PLUGIN_PATH and PYTHONPATH.

    Use them with:  eval "$(trafficcal gst-env)"  then  gst-launch-1.0 ... ! vpdetect ! ...
    (`. scripts/env.sh` does the same). See docs/gstreamer.md. Fails, printing nothing to stdout, when GStreamer's
    Python plugin loader is not installed (the exports would be of no use).
    """
    require_plugin_loader()
    click.echo(shell_exports(gst_environment(plugin_dirs=plugin_dirs)), nl=False)
