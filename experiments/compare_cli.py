"""The ``rtfit compare`` command (`rtfit.experiments.compare`): frames a user's engine rendered against the
path-traced reference of the same Mitsuba XML scene.

    rtfit compare SCENE.xml FRAME.exr [FRAME2.exr[:layer] | FRAME.png …] [--quantity Q] [--ao-radius R]
                  [--aov depth=D.exr,normal=N.exr,albedo=A.exr] [--fit-exposure] [--footprint box|centre]
                  [--camera-path sensors|static|POSES.json] [-D name=value ...] [--camera N] [--variant V]
                  [--spp N] [--pass-spp N] [--out DIR] [--cache DIR] [--seed S] [--no-progress]

Bad input is one line, ``rtfit: error: …``, exit status 2, nothing rendered or written. A frame that is not
within the reference's noise, or a step of a sequence that flickers (a failed check), exits with status 1
after the report is written.
"""

from __future__ import annotations

import click

from .audit import AuditError
from .audit_cli import input_error, parse_defines
from .cli_options import cache_option, out_option, pass_spp_option, spp_option, variant_option
from .cli_run import settings_keywords
from .compare import FOOTPRINTS, QUANTITIES
from .compare import compare as run_compare

__all__ = ["compare"]


@click.command("compare")
@click.argument("scene")
@click.argument("frames", nargs=-1)
@click.option(
    "--quantity",
    type=click.Choice(list(QUANTITIES)),
    default="radiance",
    show_default=True,
    help="What the frames show: radiance (the scene's integrator), direct (max_depth 2), irradiance (W/m² "
    "at the first hit), ao (visibility 0..1 at the first hit) or transmittance (camera ray to the first "
    "surface).",
)
@click.option(
    "--ao-radius",
    type=float,
    default=float("inf"),
    show_default=True,
    help="With --quantity ao: the occlusion radius (scene units; inf: unbounded).",
)
@click.option(
    "--aov",
    multiple=True,
    metavar="depth=D.exr,normal=N.exr,albedo=A.exr",
    help="The frames' depth AOV (ray distance or planar depth), normal AOV (world or view space) and albedo "
    "AOV (linear BSDF reflectance): their alignment with the scene's camera; the albedo also splits a "
    "radiance frame's error into albedo and lighting.",
)
@click.option(
    "--fit-exposure", is_flag=True, help="Compare the frames after dividing by their best global scale."
)
@click.option(
    "--footprint",
    type=click.Choice(list(FOOTPRINTS)),
    default="box",
    show_default=True,
    help="Reference samples over each pixel's area (box: antialiased frames) or at its centre.",
)
@click.option(
    "--camera-path",
    default=None,
    metavar="sensors|static|POSES.json",
    help="The frames are a sequence (with its temporal stability): frame i through the scene's sensor i "
    "(sensors), every frame through --camera (static), or frame i through --camera moved to pose i of a "
    "JSON list of {origin, target, up, fov} or 4×4 to_world matrices.",
)
@click.option("-D", "defines", multiple=True, metavar="NAME=VALUE", help="A Mitsuba XML parameter ($NAME).")
@click.option("--camera", type=click.IntRange(min=0), default=0, show_default=True, help="XML sensor index.")
@variant_option("Mitsuba variant of the reference.")
@spp_option()
@pass_spp_option()
@out_option("Output directory: the report goes to OUT/compare-<scene>.")
@cache_option()
@click.option("--seed", type=click.IntRange(min=0, max=2**31 - 1), default=0, show_default=True)
@click.option("--no-progress", is_flag=True, help="No progress bars.")
def compare(
    scene,
    frames,
    quantity,
    ao_radius,
    aov,
    fit_exposure,
    footprint,
    camera_path,
    defines,
    camera,
    out,
    **run_options,
):
    """Compare FRAMES (OpenEXR, FRAME.exr:layer, or PNG) rendered by your engine with the path-traced
    reference of SCENE (Mitsuba XML) through its own sensor: metrics beside the reference's noise, the best
    global scale, the registration offset, the error per shape, and a report in OUT/compare-<scene>."""
    if not frames:
        input_error("no frame to compare (rtfit compare SCENE.xml FRAME.exr …)")
    defs = parse_defines(defines)
    try:
        result = run_compare(
            scene, frames, quantity=quantity, out=out, defines=defs, camera=camera, fit_exposure=fit_exposure,
            aov=aov, footprint=footprint, camera_path=camera_path, ao_radius=ao_radius,
            **settings_keywords(run_options),
        )  # fmt: skip
    except AuditError as e:
        input_error(str(e))
    for f in result.frames:
        a = f.analysis
        click.echo(f"{f.label}: {a.verdict}")
        click.echo(
            f"  scale {a.scale:.5g} ± {a.scale_stderr:.2g}; offset ({a.offset[0]:+d}, {a.offset[1]:+d}) px"
            + (" (misaligned)" if a.misaligned else " (no misalignment)")
        )
    for step in result.temporal:
        click.echo(
            f"{step['from']} → {step['to']}: error change {step['error_change']:.3g} (noise floor "
            f"{step['noise_floor']:.2g}): " + ("stable" if step["stable"] else "flickers")
        )
    for name, a in result.frames[0].aovs.items():
        click.echo(f"{name} AOV: {a['text']}")
    assert result.out is not None
    click.echo(str((result.out / "report.html").resolve()))
    assert result.results is not None
    if any(not c.passed for c in result.results.checks):
        raise click.exceptions.Exit(1)
