"""rtfit.realtime: real-time rendering approximations as kernels written once, run on Dr.Jit, NumPy and JAX.

Imports only drjit and numpy (jax when a JAX array is passed or `JAX_OPS` is asked for). Public functions
accept Python floats, NumPy arrays (evaluated on the default Dr.Jit backend, see `set_default_backend`),
Dr.Jit arrays (same type out) or JAX arrays (JAX out, differentiable); see `rtfit.realtime.arrays`.

Every public name of every module below is importable from this package's root
(``from rtfit.realtime import sphere_light_irradiance, height_fog_optical_depth``), whatever module it
lives in, so that moving a function between modules never breaks a user.

Modules:
    arrays      the ops namespaces (Dr.Jit, NumPy, JAX), dispatch, guards and small stable helpers.
    methods     methods as data: `Method`, `Param`, `Input`, `method_table`.
    phase       phase functions (Rayleigh, Henyey–Greenstein, Cornette–Shanks), one text for all media.
    ambient_aperture  ambient aperture lighting: exact / smoothstep / fitted spherical-cap intersection
                and shading (docs/ambient-aperture.md).
    aerial_perspective  single scattering through the Nishita atmosphere + height fog together, the
                seed's horizon-matched fog colour (docs/aerial-perspective.md).
    diffuse     Lambert, half-Lambert, wrap lighting, exact sphere-light irradiance (docs/diffuse.md).
    light_models  the diffuse family's light models from the light's own parameters: punctual, Unreal and
                Frostbite windows, representative point, LTC polygon and disc, spot cones (docs/diffuse.md);
                the exact sphere-light kernel text.
    environment_bases  every irradiance basis of an environment as one method table (the irradiance-bases
                family: cube, SH, ZH3, SG, Ambient Dice; ``METHODS`` from the module).
    environment_maps  pre-convolved and localised cube maps, cosine look-up, distance-impostor Hit
                (docs/environment-maps.md).
    reflections  the environment-maps family on a user's shape: classic, distance-impostor and
                pre-convolved cube-map lookups of a probe at the shape's centre (``METHODS``; docs/audit.md).
    irradiance_bases  irradiance bases: ambient cube (Valve, NNLS), SH L1/L2, windowed SH, Geomerics L1
                (docs/irradiance-bases.md).
    irradiance_volumes  irradiance volumes: a grid of ambient-cube / SH L2 probes, nearest and trilinear
                lookup, point-light folding (docs/irradiance-volumes.md; ``METHODS`` from the module).
    spherical_gaussians  spherical-Gaussian irradiance bases (N = 6, 9, 12 lobes; naive / LS / NNLS /
                ambient fits; SG ⊗ clamped cosine) (docs/irradiance-bases.md).
    ambient_dice  Ambient Dice (Iwanicki & Sloan 2017), RBF variant on 12 icosahedron vertices.

    hemisphere_bases  lightmap (hemispherical) irradiance bases: H-basis (4, 6), Half-Life 2 radiosity
                normal mapping (docs/irradiance-bases.md).
    linear_fog  classic distance fog (linear, exp, exp², the seed's luminance-faded linear fog) and
                Beer–Lambert transmittance (docs/linear-fog.md).
    height_fog  exponential height fog: stable closed-form optical depth, fog colour, fog volumes
                (docs/height-fog.md).
    sdf_grid    signed distance fields: analytic primitives, mesh → voxel grid, mip chain, 8-bit
                (docs/sdf-occlusion.md).
    sdf_occlusion  Evans multi-scale SDF skylight/occlusion, curvature term, cone-traced soft occlusion.
    nishita_sky Nishita single-scattering sky texture, atmosphere optical depth, aerial perspective
                (docs/nishita-sky.md).
    layered_materials  the seed's layered ("goopy") materials: the inner layer's parallax offset without
                refraction vs Snell's refracted offset; blur radii and composite (docs/layered-materials.md).
    clouds      the seed's cloud shadows: a 2-D density plane projected along the sun, the plane extruded
                and marched, a 3-D ray march of the cloud's grid (docs/clouds.md).
    misty_glow  the seed's misty glow: an iterated Kawase bloom of a light's direct image as the
                atmospheric point-spread function; a Gaussian bloom (docs/misty-glow.md).
    raindrops   the seed's raindrop: a Fresnel blend of a reflected and a once-refracted environment
                look-up vs the ray optics of a sphere (two refractions, internal reflections)
                (docs/raindrops.md).
    volumetric_lightning  the seed's volumetric lightning (softened point light gathered along the view
                segment) in a float32-stable closed form; single scattering without extinction
                (docs/volumetric-lightning.md). The package attribute ``volumetric_lightning`` is the
                function (the issue's public name), so the module's names are imported with
                ``from rtfit.realtime.volumetric_lightning import METHODS`` (``import
                rtfit.realtime.volumetric_lightning as m`` binds the function).
    soft_particles  soft particles: depth fade, camera-aligned box, spherical billboards vs the exact
                clipped Beer–Lambert chord (docs/soft-particles.md).
    light_cones the seed's light-cone shell in fog (edge fade, v^q attenuation) and §1's integral over the
                view ray's chord through a spot light's cone (docs/light-cones.md).
    parallax_occlusion  parallax occlusion mapping with soft self-shadowing: the seed's listing and a
                stable variant, procedural height fields (docs/parallax-occlusion.md).

    fresnel     Fresnel reflectance: Schlick (from the IOR, fitted exponent), the seeds' slider, rim and metal
                forms, Hoffman's F82 tint, the exact dielectric and conductor Fresnel (docs/fresnel.md).
    sh_sky_bent_normal  sky ambient from the sky's SH along the bent normal (the seed's radiance
                lookup × AO), the SH irradiance at the bent normal / normal × AO, the visible cone
                (docs/sh-sky-bent-normal.md).
    pcf_soft_shadows  percentage-closer filtering of a shadow map for an area light's penumbra: the seed's
                8-tap Poisson PCF (fixed, rotated), box PCF, PCSS; the `ShadowMap` (docs/pcf-soft-shadows.md).
    ibl_samples image-based lighting from N directional lights baked from an environment map (the seed's
                energy samples + Lloyd relaxation, median cut), each with its own shadow
                (docs/ibl-samples.md).
    colour_bleeding  stand-ins for one diffuse bounce per channel: the seed's per-channel SDF bias, RGB
                obscurances' colour part, a one-bounce gather (docs/colour-bleeding.md).
    light_path_maps  one diffuse bounce from a moving light as clustered virtual lights: the seed's path
                maps (entry points, k-means clusters, the cut, the run-time blend) (docs/light-path-maps.md).
    probe_specular  glossy specular from the nearest pre-rendered cube map pre-convolved per roughness
                (GGX chain, roughness → mip), Lagarde's box/sphere parallax correction
                (docs/probe-specular.md).
    obscurances Zhukov/Iones obscurances: distance functions ρ (power, exponential, step) and the K-ray
                estimator (docs/obscurances.md).
    quantities  what an approximation approximates and the inputs its ``g`` carries; the `approximation`
                decorator for a user's own formula (docs/audit.md, "Your own approximation"); the table's
                rooms: quantity_types (the `Quantity` record, shared inputs), quantities_lights,
                quantities_sky, quantities_media, quantities_probes, quantities_materials.
    shader      GLSL/HLSL text traced from the kernels (`SHADER_OPS`, `shader_function`).
"""

# Star imports re-export each module's ``__all__`` (tests/test_layering.py checks that every public
# function of every module is in its ``__all__`` and that no two modules export the same name).
from . import arrays
from .aerial_perspective import *  # noqa: F403
from .ambient_aperture import *  # noqa: F403
from .ambient_dice import *  # noqa: F403
from .arrays import *  # noqa: F403
from .caustics import *  # noqa: F403
from .clouds import *  # noqa: F403
from .colour_bleeding import *  # noqa: F403
from .diffuse import *  # noqa: F403
from .environment_bases import *  # noqa: F403
from .environment_maps import *  # noqa: F403
from .fresnel import *  # noqa: F403
from .height_fog import *  # noqa: F403
from .hemisphere_bases import *  # noqa: F403
from .ibl_samples import *  # noqa: F403
from .irradiance_bases import *  # noqa: F403
from .irradiance_volumes import *  # noqa: F403
from .layered_materials import *  # noqa: F403
from .light_cones import *  # noqa: F403
from .light_models import *  # noqa: F403
from .light_path_maps import *  # noqa: F403
from .linear_fog import *  # noqa: F403
from .methods import *  # noqa: F403
from .misty_glow import *  # noqa: F403
from .nishita_sky import *  # noqa: F403
from .obscurances import *  # noqa: F403
from .parallax_occlusion import *  # noqa: F403
from .pcf_soft_shadows import *  # noqa: F403
from .phase import *  # noqa: F403
from .probe_specular import *  # noqa: F403
from .quantities import *  # noqa: F403
from .quantities_lights import *  # noqa: F403
from .quantities_materials import *  # noqa: F403
from .quantities_media import *  # noqa: F403
from .quantities_probes import *  # noqa: F403
from .quantities_sky import *  # noqa: F403
from .quantity_types import *  # noqa: F403
from .raindrops import *  # noqa: F403
from .reflections import *  # noqa: F403
from .sdf_grid import *  # noqa: F403
from .sdf_occlusion import *  # noqa: F403
from .sh_sky_bent_normal import *  # noqa: F403
from .shader import *  # noqa: F403
from .soft_particles import *  # noqa: F403
from .spherical_gaussians import *  # noqa: F403
from .volumetric_lightning import *  # noqa: F403

MODULES = (
    "arrays",
    "methods",
    "phase",
    "ambient_aperture",
    "diffuse",
    "light_models",
    "environment_maps",
    "reflections",
    "height_fog",
    "linear_fog",
    "layered_materials",
    "misty_glow",
    "raindrops",
    "clouds",
    "irradiance_bases",
    "irradiance_volumes",
    "spherical_gaussians",
    "ambient_dice",
    "environment_bases",
    "hemisphere_bases",
    "sdf_grid",
    "sdf_occlusion",
    "nishita_sky",
    "volumetric_lightning",
    "aerial_perspective",
    "soft_particles",
    "light_cones",
    "parallax_occlusion",
    "obscurances",
    "fresnel",
    "sh_sky_bent_normal",
    "pcf_soft_shadows",
    "ibl_samples",
    "colour_bleeding",
    "light_path_maps",
    "caustics",
    "probe_specular",
    "quantity_types",
    "quantities_lights",
    "quantities_sky",
    "quantities_media",
    "quantities_probes",
    "quantities_materials",
    "quantities",
    "shader",
)
"""The modules whose public names this package re-exports."""


def __getattr__(name: str):
    # JAX_OPS is built on first use (it imports jax): see rtfit.realtime.arrays.
    if name == "JAX_OPS":
        return arrays.jax_ops()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
