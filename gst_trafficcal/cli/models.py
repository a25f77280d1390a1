"""``trafficcal models``: install detector ONNX files into the per-user cache and list them."""

from __future__ import annotations

import click


@click.group(name="models")
def command() -> None:
    """Detector models in the per-user cache ($XDG_CACHE_HOME/gst-trafficcal/models).

    Installed models can be given to vehicledetect by file name: model=NAME.onnx.
    """


@command.command(name="install")
@click.argument("source")
@click.option("--sha256", "sha256", required=True, help="Expected SHA-256 of the file (64 hex digits).")
@click.option("--name", default=None, help="File name in the cache (default: the source's file name).")
@click.option("--force", is_flag=True, help="Replace a different model installed under the same name.")
def install_cmd(source: str, sha256: str, name: str | None, force: bool) -> None:
    """Verify and copy SOURCE (a URL or a local path) into the model cache; print where it is.

    A different model already installed under the same name is kept unless --force is given; the same file
    again changes nothing.
    """
    from ..detection.models import install

    done = install(source, sha256, name, force=force)
    click.echo(str(done.path))  # stdout: the path alone, for scripts; what happened on stderr
    if done.action == "unchanged":
        click.echo(f"trafficcal: {done.path.name} was installed already (the same file): nothing changed", err=True)
    elif done.action == "replaced":
        click.echo(f"trafficcal: replaced the model installed as {done.path.name}", err=True)


@command.command(name="list")
def list_cmd() -> None:
    """List installed models: name, size, SHA-256, path (and why, for a file that cannot be read)."""
    from ..detection.models import cache_dir, list_models

    entries = list_models()
    if not entries:
        click.echo(f"no models installed in {cache_dir()}")
        return
    for e in entries:
        if e.problem:
            click.echo(f"{e.name}\t{'-' if e.size is None else e.size}\t-\t{e.path}\t{e.problem}")
        else:
            click.echo(f"{e.name}\t{e.size}\t{e.sha256}\t{e.path}")
