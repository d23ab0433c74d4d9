"""``edge-ips config`` (show, init) and ``edge-ips schema``: the configuration and the message contract as files."""

from __future__ import annotations

from pathlib import Path

import click

from edge.cli.common import EdgeGroup, config_option, load


@click.command()
@click.option(
    "--out",
    "out_dir",
    type=click.Path(file_okay=False, path_type=Path),
    default=Path("shared/schema"),
    show_default=True,
    help="Directory to write the JSON Schema files into.",
)
def schema(out_dir: Path) -> None:
    """Write the JSON Schemas of the message contract (pose, formation and status v1, rover status v2).

    Example:

        edge-ips schema --out shared/schema
    """
    from edge.messages import write_schemas

    for path in write_schemas(out_dir):
        click.echo(f"wrote {path}")


@click.group(cls=EdgeGroup)
def config() -> None:
    """Show or start the TOML configuration.

    Example:

        edge-ips config show
    """


@config.command("show")
@config_option
@click.option("--json", "as_json", is_flag=True, help="JSON instead of TOML.")
def config_show(config_path: Path | None, as_json: bool) -> None:
    """Print the effective configuration (file, environment overrides, defaults) with secrets masked.

    Example:

        EDGE_IPS_BROKER__URL=mqtt://pi:1883 edge-ips config show
    """
    import json

    from edge.config_text import masked, to_toml

    loaded = load(config_path)
    data = masked(loaded.config)
    if as_json:
        click.echo(json.dumps(data, indent=2))
        return
    overrides = f" + environment ({', '.join(loaded.env_keys)})" if loaded.env_keys else ""
    click.echo(f"# effective configuration: {loaded.where}{overrides}")
    click.echo(to_toml(data), nl=False)


@config.command("init")
@click.argument("path", type=click.Path(dir_okay=False, path_type=Path), default=Path("edge-ips.toml"))
@click.option("--force", is_flag=True, help="Overwrite an existing file.")
def config_init(path: Path, force: bool) -> None:
    """Write a commented starting configuration file.

    Example:

        edge-ips config init /etc/edge-ips/config.toml
    """
    from edge.config_text import write_starter

    click.echo(f"wrote {write_starter(path, force=force)}")
