"""A user's Mitsuba 3 XML scene, read by Mitsuba's own parser (``mitsuba.parser``, Mitsuba 3.9).

Mitsuba's parser resolves ``<include>``, ``<path>``, ``<default>``/``$name`` parameters and ``<ref>``
exactly as ``mitsuba`` itself does, and records every XML file it read (`ParserState.files`). Data files
(meshes, textures, environment maps, spectra) are named by ``filename`` properties and found through the
file resolver, which ``<path>`` elements extend while the file is parsed. `xml_dependencies` collects
both, so that a reference's cache key covers **every file the scene loads**: edit a mesh three folders
away, reached through an ``<include>`` and a ``<path>``, and the key changes (a key over the files beside
the XML missed exactly that, and returned a stale reference).

Side effects are scoped: the parser adds ``<path>`` folders to Mitsuba's process-wide file resolver;
`xml_dependencies` and `inspect_xml` parse with a resolver of their own (a copy of the caller's, so that
plugins are still found) and put the caller's back afterwards, and the caller's Mitsuba variant too.

`inspect_xml` reads what the scene contains — sensors, emitters, shapes, BSDFs, media, the integrator —
from the parser's state, and instantiates the scene (`mitsuba.parser.instantiate`, under the same scoped
resolver) for what the properties do not say: the film size and field of view Mitsuba derives (defaults,
``focal_length``), the mesh face counts and the bounding boxes (a sphere light's centre and radius, the
scene's extent). Instantiating also loads every mesh, so a mesh Mitsuba cannot read (a PLY with
non-triangular faces: Mitsuba 3.9's PLY loader takes triangles only) is an `XMLSceneError` here, naming
the XML file and line that declares it.

Errors: a file Mitsuba refuses becomes one `XMLSceneError` line naming the file and line, as Mitsuba
reports them (e.g. ``scene.xml: Error while loading scene.xml (line 9, col 6): encountered an unsupported XML
element: <widget>``), without Mitsuba's source-location prefixes. Before Mitsuba parses a file,
`rtfit.reference.xml_checks.prescan` refuses what would crash its parser (deep nesting), entity declarations,
a newer ``version`` and XML that is not well-formed; before the scene is instantiated, `check_values` checks
every value against the TOML scene's ranges and `mesh_problem` every mesh file (issue 32).

Rooms: `rtfit.reference.xml_parse` (the scoped parser, errors, node values, checks, `xml_dependencies`),
`rtfit.reference.xml_records` (`XmlScene` and its records), `rtfit.reference.xml_inspect` (`inspect_xml`),
`rtfit.reference.xml_media` (the medium a light sits in: `point_medium`); this module keeps `loaded_xml`
(a scene instantiated for rendering) and re-exports the others' public names (`__all__`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from .xml_inspect import inspect_xml, up_from_vector
from .xml_media import MAX_CROSSINGS, OUTER, camera_origin, first_transition, point_medium
from .xml_parse import (
    DICT_SOURCE,
    NOT_TEXT_ERROR,
    XmlDependencies,
    XMLSceneError,
    check_nodes,
    instantiate_checked,
    mitsuba_error_text,
    node_props,
    normalised_source,
    parsed_xml,
    plain_value,
    source_label,
    xml_dependencies,
)
from .xml_records import UP_AXES, Vec3, XmlEmitter, XmlMedium, XmlScene, XmlSensor, XmlShape

__all__ = [
    "DICT_SOURCE",
    "MAX_CROSSINGS",
    "OUTER",
    "UP_AXES",
    "LoadedXml",
    "Vec3",
    "XMLSceneError",
    "XmlDependencies",
    "XmlEmitter",
    "XmlMedium",
    "XmlScene",
    "XmlSensor",
    "XmlShape",
    "camera_origin",
    "first_transition",
    "inspect_xml",
    "loaded_xml",
    "point_medium",
    "up_from_vector",
    "xml_dependencies",
]


@dataclass(frozen=True)
class LoadedXml:
    """A Mitsuba XML scene instantiated for rendering (`loaded_xml`): ``mi`` (the module, in the scoped
    variant), ``scene``, the chosen ``sensor`` (its film resized by ``--width``/``--height``) and
    ``emitters``: the Mitsuba emitter objects in the document order of `XmlScene.emitters`."""

    mi: object
    scene: object
    sensor: object
    emitters: tuple


@contextlib.contextmanager
def loaded_xml(
    path: str | os.PathLike | Mapping,
    defines: Mapping[str, str] | None = None,
    variant: str = "llvm_ad_rgb",
    *,
    camera: int = 0,
    width: int | None = None,
    height: int | None = None,
) -> Iterator[LoadedXml]:
    """Instantiate the XML scene ``path`` (or a scene dict, `XmlScene.source`) in ``variant`` (scoped: the
    caller's variant and file resolver are put back on exit) with only what the file declares: Mitsuba's
    parser, then the chosen sensor's film resized (``width``/``height``; the field of view along
    ``fov_axis`` is kept), each emitter tagged so
    that the rendered objects are matched to the document's emitters one to one. Raises `XMLSceneError`
    (one line) for anything Mitsuba refuses."""
    path, defines = normalised_source(path, defines)
    label = source_label(path)
    with parsed_xml(path, defines, variant) as (mi, parser, config, state, unread):
        config.merge_meshes = False
        config.merge_equivalent = False
        try:
            parser.transform_all(config, state)
            nodes = list(state.nodes)
            kinds = [str(n.type).rsplit(".", 1)[-1] for n in nodes]
            emitter_nodes = [i for i, k in enumerate(kinds) if k == "Emitter"]
            for k, i in enumerate(emitter_nodes):  # references are resolved already: ids are free now
                nodes[i].props.set_id(f"rtfit-emitter-{k}")
            sensors = [i for i, k in enumerate(kinds) if k == "Sensor"]
            if sensors and not 0 <= camera < len(sensors):
                last = len(sensors) - 1
                raise XMLSceneError(
                    f"{label}: --camera {camera}: the scene has {len(sensors)} sensor(s), 0..{last}"
                )
            if not sensors:
                raise XMLSceneError(
                    f"{label}: the scene has no <sensor> (the audit renders the scene's own view)"
                )
            check_nodes(
                mi,
                nodes,
                kinds,
                [node_props(n) for n in nodes],
                [parser.file_location(state, n) for n in nodes],
                camera,
            )
            films = _films_of(state, nodes, kinds, sensors[camera])
            for film in films:
                if width is not None:
                    film.props["width"] = int(width)
                if height is not None:
                    film.props["height"] = int(height)
            scene = instantiate_checked(parser, config, state, unread)
        except RuntimeError as e:
            raise XMLSceneError(f"{label}: {mitsuba_error_text(e)}") from None
        except UnicodeDecodeError:
            raise XMLSceneError(f"{label}: {NOT_TEXT_ERROR}") from None
        if isinstance(scene, list | tuple) or not hasattr(scene, "sensors"):
            raise XMLSceneError(f"{label}: the file's root is not a <scene>")
        by_id = {e.id(): e for e in scene.emitters()}
        emitters = tuple(by_id.get(f"rtfit-emitter-{k}") for k in range(len(emitter_nodes)))
        yield LoadedXml(mi, scene, scene.sensors()[camera], emitters)


def _films_of(state, nodes, kinds, sensor_index: int) -> list:
    """The film node(s) a sensor node refers to (its ``_arg_*``/named references)."""
    out = []
    for key in nodes[sensor_index].props.keys():
        value = plain_value(nodes[sensor_index].props[key])
        if isinstance(value, tuple) and value[:1] == ("ref",) and kinds[value[1]] == "Film":
            out.append(nodes[value[1]])
    return out
