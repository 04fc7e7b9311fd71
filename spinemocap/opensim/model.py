"""The multi-segment spine model, built through OpenSim's Python API from a :class:`SpineGeometry`.

Bodies (caudal -> cranial): ``pelvis`` (free in ground, its origin at the S1 body centre),
``sacrum`` (welded to it), ``L5`` ... ``L1``, ``T12`` ... ``T1``, ``head_neck`` (thorax above
T1 with head and neck). Units: metres, kg; body frames X anterior, Y superior, Z right (ISB).

Joints between adjacent vertebrae are ``CustomJoint`` s named by the disc (``L4_L5``: child L4,
parent L5) with three body-fixed rotations in the order Z, X, Y:

- ``<joint>_extension`` about Z (right): **extension positive** (OpenSim's usual sign; this
  project's flexion is its negative),
- ``<joint>_lateral_bending`` about X (anterior): toward the subject's right positive,
- ``<joint>_axial_rotation`` about Y (superior): toward the subject's left positive.

Zero is the static trial's posture (the model is built in it). Only joints the tape can drive
carry coordinates: a joint gets them when tape markers sit on bodies both below and above it;
the others are ``WeldJoint`` s (a locked coordinate still costs IK time; a weld costs nothing).
Coupling (``CoordinateCouplerConstraint`` s with the ratios of the published ranges of motion,
:mod:`spinemocap.anatomy`), see :func:`plan_model`: by default only a vertebra the tape
cannot resolve on its own (no full row of dots over it) has its rotations coupled to its
neighbour's; ``coupling="region"`` couples every level's lateral bending and axial rotation per
region (lumbar: L5/S1 ... T12/L1; thoracic: T11/T12 ... C7/T1) as the published lumbar and
thoracolumbar models do. On request the free per-level lateral bending and axial rotation also
get a weak prior toward the static posture in the IK set-up
(:func:`spinemocap.opensim.pipeline._priors`).

Ranges: every driven coordinate is clamped to :data:`RANGE_FACTOR` x the published range of its
motion segment (:mod:`spinemocap.anatomy`): inverse kinematics cannot leave it.

Skin: a tape row that slips (:mod:`spinemocap.opensim.skin_model`) carries its markers on a body
``R06_skin`` joined to its vertebra by ``R06_skin_slip_joint``, a translation along the vertebra's
superior axis (Y) with the coordinate ``R06_skin_slip`` (m, 0 = the static trial, clamped to the
prior's limit); the model file notes each slip coordinate's prior beside it (its goal per frame is
``skin_slip_goals.sto``, the coordinate file of ``setup_ik.xml``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..anatomy import ANATOMY
from .geometry import HEAD_NECK, SpineGeometry
from .skin_model import SlipPrior, prior_text, skin_body, slip_coordinate

DOF = ("extension", "lateral_bending", "axial_rotation")
AXES = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))  # Z, X, Y body-fixed
ROOT_COORDS = ("pelvis_tilt", "pelvis_list", "pelvis_rotation", "pelvis_tx", "pelvis_ty", "pelvis_tz")
BODY_MASS_KG = 70.0  # generic adult: masses do not enter inverse kinematics
# Driven coordinates are clamped at this multiple of the published (representative) range: above the
# tables' upper limits (~1.5-2 x the representative values, White & Panjabi 1990) so that individual
# spread stays inside, while a single thoracic level can no longer take tens of degrees.
RANGE_FACTOR = 3.0
SKIN_BODY_MASS_KG = 0.001


def body_name(name: str) -> str:
    """Chain name -> model body name (S1 is carried by the sacrum)."""
    return "sacrum" if name == "S1" else name


def joint_name(child: str, parent: str) -> str:
    """``L4``, ``L5`` -> ``L4_L5``; ``L5``, ``S1`` -> ``L5_S1``; ``head_neck``, ``T1`` -> ``C7_T1``."""
    return f"{'C7' if child == HEAD_NECK else child}_{parent}"


def region_of(child: str) -> str:
    """Region of the joint below ``child``: lumbar for L5/S1 ... T12/L1, thoracic above."""
    return "lumbar" if child[0] == "L" or child == "T12" else "thoracic"


@dataclass
class JointPlan:
    """One intervertebral joint: its chain indices, whether the tape drives it, and its ranges."""

    child: str
    parent: str
    index: int  # chain index of the child
    driven: bool
    rom_deg: tuple[float, float, float]  # extension (+/-), lateral (+/-), axial (+/-)

    @property
    def name(self) -> str:
        return joint_name(self.child, self.parent)

    @property
    def region(self) -> str:
        return region_of(self.child)

    def coordinate(self, dof: str) -> str:
        return f"{self.name}_{dof}"


@dataclass
class ModelPlan:
    """What :func:`build_model` builds: joints (driven or welded), couplers and markers."""

    joints: list[JointPlan]
    couplers: list[tuple[str, str, float]] = field(default_factory=list)  # (dependent, independent, ratio)

    @property
    def coordinates(self) -> list[str]:
        return list(ROOT_COORDS) + [j.coordinate(d) for j in self.joints if j.driven for d in DOF]

    @property
    def driven(self) -> list[JointPlan]:
        return [j for j in self.joints if j.driven]


COUPLINGS = ("rows", "region")


def plan_model(geometry: SpineGeometry, marker_bodies: np.ndarray, row_bodies: np.ndarray,
               coupling: str = "rows") -> ModelPlan:
    """Which joints the tape drives (markers on bodies below and above) and which coordinates
    are coupled. ``marker_bodies``: chain index of each placed marker; ``row_bodies``: chain
    indices of the vertebrae that carry a full tape row (L and R dots) in the static trial.

    ``coupling="rows"``: a vertebra with a full row of its own shows its lateral bending and
    axial rotation directly (the tilt and twist of the L->R axis), so its joint stays free; a
    driven vertebra without one gets all three rotations coupled to the nearest vertebra below
    (else above) that has a row, with the published range ratios. ``"region"``: as the
    published models, every driven joint's lateral bending and axial rotation coupled to the
    region's lowest driven joint (flexion/extension free per level)."""
    if coupling not in COUPLINGS:
        raise ValueError(f"unknown coupling {coupling!r}; choose from {COUPLINGS}")
    lo, hi = int(marker_bodies.min()), int(marker_bodies.max())
    joints = []
    for k in range(1, len(geometry.names)):
        joints.append(JointPlan(geometry.names[k], geometry.names[k - 1], k, lo <= k - 1 and k <= hi,
                                _rom(geometry.names[k])))
    plan = ModelPlan(joints)
    if coupling == "region":
        for region in ("lumbar", "thoracic"):
            members = [j for j in plan.driven if j.region == region]
            for j in members[1:]:
                _couple(plan, j, members[0], (1, 2))
        return plan
    with_rows = [j for j in plan.driven if j.index in {int(b) for b in row_bodies}]
    for j in plan.driven:
        if j in with_rows or not with_rows:
            continue
        below = [a for a in with_rows if a.index < j.index]
        anchor = below[-1] if below else min(with_rows, key=lambda a: a.index)
        _couple(plan, j, anchor, (0, 1, 2))
    return plan


def _couple(plan: ModelPlan, dependent: JointPlan, independent: JointPlan, axes: tuple[int, ...]) -> None:
    for axis in axes:
        ratio = dependent.rom_deg[axis] / independent.rom_deg[axis]
        plan.couplers.append((dependent.coordinate(DOF[axis]), independent.coordinate(DOF[axis]), ratio))


def _rom(child: str) -> tuple[float, float, float]:
    """Published range per joint below ``child`` (head_neck: T1's segment values)."""
    v = ANATOMY["T1" if child == HEAD_NECK else child]
    return v.flexion_extension_rom, v.lateral_rom, v.axial_rom


def _vec3(osim, v) -> object:
    return osim.Vec3(float(v[0]), float(v[1]), float(v[2]))


def _euler_xyz(R: np.ndarray) -> np.ndarray:
    """OpenSim frame orientations are body-fixed X-Y-Z angles (rad)."""
    return Rotation.from_matrix(R).as_euler("XYZ")


def _segment_body(osim, name: str, geometry: SpineGeometry, k: int):
    """A body with mass after Pearsall et al. (see anatomy) and an ellipsoid of the vertebral body."""
    v = ANATOMY.get(name if name != HEAD_NECK else "T1")
    share = {"S1": 0.0}.get(name, (v.mass_share if v else 1.1) / 100.0)
    if name == HEAD_NECK:
        share = 0.081 + 0.2  # head-neck 8.1 % (Dempster 1955, as tabulated by Winter) + upper thorax
    mass = max(share, 0.005) * BODY_MASS_KG
    s = geometry.scale / 1000.0
    width = (v.body_width if v else 28.0) * s
    depth = (v.body_depth if v else 16.0) * s
    height = (v.body_height if v else 15.0) * s
    inertia = osim.Inertia(mass * (height**2 + width**2) / 20, mass * (depth**2 + width**2) / 20,
                           mass * (depth**2 + height**2) / 20)
    body = osim.Body(body_name(name), mass, osim.Vec3(0), inertia)
    body.attachGeometry(osim.Ellipsoid(depth / 2, height / 2, width / 2))
    return body


def _transform_axis(osim, st, index: int, coordinate: str | None, axis) -> None:
    ta = st.updTransformAxis(index)
    ta.setAxis(_vec3(osim, axis))
    if coordinate is None:
        ta.set_function(osim.Constant(0.0))
        return
    names = osim.ArrayStr()
    names.append(coordinate)
    ta.setCoordinateNames(names)
    ta.set_function(osim.LinearFunction(1.0, 0.0))


def _custom_joint(osim, name: str, parent, parent_loc, parent_R, child, child_loc, coords: list[str | None]):
    """A CustomJoint with rotations Z, X, Y then translations X, Y, Z; ``coords`` names the six
    coordinates (None = that axis is not used); locations in m, ``parent_R`` the child's
    orientation in the parent frame at zero coordinates."""
    st = osim.SpatialTransform()
    for i, axis in enumerate(AXES + ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0))):
        _transform_axis(osim, st, i, coords[i], axis)
    return osim.CustomJoint(name, parent, _vec3(osim, parent_loc), _vec3(osim, _euler_xyz(parent_R)),
                            child, _vec3(osim, child_loc), osim.Vec3(0), st)


def build_model(geometry: SpineGeometry, plan: ModelPlan, markers: list[tuple[str, int, np.ndarray, int]],
                slips: dict[int, int] | None = None, prior: SlipPrior | None = None,
                name: str = "spinemocap_spine"):
    """The OpenSim model (``opensim.Model``, finalized). ``markers``: (label, chain index,
    location in that body's frame (mm), tape row); ``slips``: {tape row: chain index of its
    vertebra} of the rows that slip (their markers go on the row's skin body, same location)."""
    import opensim as osim

    model = osim.Model()
    model.setName(name)
    model.setGravity(osim.Vec3(0, -9.80665, 0))
    mm = 1.0 / 1000.0
    bodies = {}
    pelvis = _segment_body(osim, "S1", geometry, 0)
    pelvis.setName("pelvis")
    pelvis.setMass(0.142 * BODY_MASS_KG)  # pelvis 14.2 % (Dempster 1955, as tabulated by Winter)
    model.addBody(pelvis)
    root = _custom_joint(osim, "ground_pelvis", model.getGround(), geometry.centre[0] * mm, geometry.frame[0],
                         pelvis, np.zeros(3), list(ROOT_COORDS))
    model.addJoint(root)
    sacrum = osim.Body("sacrum", 0.5, osim.Vec3(0), osim.Inertia(1e-3, 1e-3, 1e-3))
    model.addBody(sacrum)
    model.addJoint(osim.WeldJoint("pelvis_sacrum", pelvis, osim.Vec3(0), osim.Vec3(0), sacrum, osim.Vec3(0), osim.Vec3(0)))
    bodies[0] = sacrum
    for j in plan.joints:
        k = j.index
        body = _segment_body(osim, j.child, geometry, k)
        model.addBody(body)
        bodies[k] = body
        R_parent, R_child = geometry.frame[k - 1], geometry.frame[k]
        joint_at = geometry.disc_centre(k)
        parent_loc = R_parent.T @ (joint_at - geometry.centre[k - 1]) * mm
        child_loc = R_child.T @ (joint_at - geometry.centre[k]) * mm
        if j.driven:
            coords = [j.coordinate(d) for d in DOF] + [None, None, None]
            joint = _custom_joint(osim, j.name, bodies[k - 1], parent_loc, R_parent.T @ R_child, body,
                                  child_loc, coords)
        else:
            joint = osim.WeldJoint(j.name, bodies[k - 1], _vec3(osim, parent_loc),
                                   _vec3(osim, _euler_xyz(R_parent.T @ R_child)), body,
                                   _vec3(osim, child_loc), osim.Vec3(0))
        model.addJoint(joint)
    _set_ranges(model, plan)
    for dependent, independent, ratio in plan.couplers:
        coupler = osim.CoordinateCouplerConstraint()
        coupler.setName(f"couple_{dependent}")
        names = osim.ArrayStr()
        names.append(independent)
        coupler.setIndependentCoordinateNames(names)
        coupler.setDependentCoordinateName(dependent)
        coupler.setFunction(osim.LinearFunction(float(ratio), 0.0))
        model.addConstraint(coupler)
    skins = {row: _skin_body(osim, model, row, bodies[k] if k > 0 else sacrum, prior or SlipPrior())
             for row, k in (slips or {}).items()}
    for label, k, location, row in markers:
        frame = skins.get(row, bodies[k] if k > 0 else sacrum)
        model.addMarker(osim.Marker(label, frame, _vec3(osim, np.asarray(location) * mm)))
    model.finalizeConnections()
    return model


def _skin_body(osim, model, row: int, vertebra, prior: SlipPrior):
    """A row's skin body on its vertebra: frames coincide at zero slip; slip along the vertebra's Y."""
    body = osim.Body(skin_body(row), SKIN_BODY_MASS_KG, osim.Vec3(0), osim.Inertia(1e-7, 1e-7, 1e-7))
    model.addBody(body)
    coords = [None, None, None, None, slip_coordinate(row), None]
    joint = _custom_joint(osim, f"{slip_coordinate(row)}_joint", vertebra, np.zeros(3), np.eye(3), body,
                          np.zeros(3), coords)
    model.addJoint(joint)
    c = model.updCoordinateSet().get(slip_coordinate(row))
    c.setRangeMin(-prior.limit_mm / 1000.0)
    c.setRangeMax(prior.limit_mm / 1000.0)
    c.setDefaultValue(0.0)
    c.setDefaultClamped(True)
    return body


def annotate_slips(model_file, prior: SlipPrior, rows: list[int]) -> None:
    """Write each slip coordinate's prior as an XML comment inside its ``Coordinate`` element of
    ``model_file`` (OpenSim ignores comments; a model re-saved by OpenSim drops them)."""
    import xml.etree.ElementTree as ET

    names = {slip_coordinate(r) for r in rows}
    tree = ET.parse(model_file, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    for element in tree.getroot().iter("Coordinate"):
        name = element.get("name")
        if name is not None and name in names:
            element.insert(0, ET.Comment(
                f" skin slip of tape row {name[:3]} along its vertebra's superior axis (m, 0 = "
                f"static trial); prior: {prior_text(prior)}; clamped to +/-{prior.limit_mm:g} mm; the rows "
                f"below the first slipping one are pinned to their vertebrae "))
    tree.write(model_file, encoding="UTF-8", xml_declaration=True)


def _set_ranges(model, plan: ModelPlan) -> None:
    """Root: rotations +/-180 deg, translations +/-5 m, unclamped; joints: :data:`RANGE_FACTOR` x
    the published ranges (deg), clamped (inverse kinematics stays inside them; frames that reach a
    limit are flagged)."""
    coords = model.updCoordinateSet()
    for name in ROOT_COORDS:
        limit = 5.0 if name.endswith(("_tx", "_ty", "_tz")) else np.pi
        coords.get(name).setRangeMin(-limit)
        coords.get(name).setRangeMax(limit)
    for j in plan.driven:
        for dof, rom in zip(DOF, j.rom_deg):
            c = coords.get(j.coordinate(dof))
            c.setRangeMin(-RANGE_FACTOR * np.radians(rom))
            c.setRangeMax(RANGE_FACTOR * np.radians(rom))
            c.setDefaultClamped(True)
