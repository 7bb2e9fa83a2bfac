"""The `duhem` command line."""
import click


@click.group()
@click.version_option(package_name="semilinear-duhem")
def main() -> None:
    """Identify semilinear Duhem hysteresis models and export them as FMUs."""
