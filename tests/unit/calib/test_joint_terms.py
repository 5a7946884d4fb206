"""Joint-space terms: the gravity torques against the potential energy, a payload lumped into the
last link, the angles the links take and the terms' TCP derivatives against finite differences."""

import numpy as np
import pytest

import configs
from calib.joint_terms import (
    G_MS2,
    JointTerms,
    LinkMasses,
    Term,
    compliance_group,
    gravity_torques,
    harmonic_group,
    load_bearing_joints,
    turn_gap,
    whole_turn_joints,
)
from calib.kinematics import base_from_frames, tcp_position
from sim_fixtures.world import Robot
from station.formats.tables import load_robot

LINKS = load_robot(configs.path("robots/ur10.toml")).link_masses()  # UR's published masses


def ur10() -> np.ndarray:
    return Robot.from_file(configs.path("robots/ur10.toml")).dh


def potential_energy(dh, q, links) -> np.ndarray:
    """V = -sum m_k g . c_k [J], per configuration."""
    fr = base_from_frames(dh, q)
    com = np.einsum("nkij,kj->nki", fr[:, 1:, :3, :3], links.com_mm) + fr[:, 1:, :3, 3]
    return -np.einsum("k,nki,i->n", links.mass_kg, com, G_MS2 * np.asarray(links.gravity)) * 1e-3


@pytest.mark.parametrize("links", [LINKS, LINKS.with_payload(5.0, [10.0, -20.0, 80.0])])
def test_gravity_torques_are_the_slope_of_the_potential_energy(rng, links):
    """tau_j = -dV/dq_j, by central differences over q."""
    dh, q = ur10(), rng.uniform(-np.pi, np.pi, (5, 6))
    joints = (1, 2, 3)
    h = 1e-6
    for c, j in enumerate(joints):
        e = np.zeros(6)
        e[j] = h
        slope = (potential_energy(dh, q + e, links) - potential_energy(dh, q - e, links)) / (2 * h)
        np.testing.assert_allclose(gravity_torques(dh, q, links, joints)[:, c], -slope, atol=1e-6)


def test_a_payload_adds_its_own_torque(rng):
    """A payload's torque is that of a point mass at its centre: m g lever, by the same formula on a
    massless arm carrying it."""
    dh, q = ur10(), rng.uniform(-np.pi, np.pi, (5, 6))
    payload = (5.0, np.array([10.0, -20.0, 80.0]))
    massless = LinkMasses(np.zeros(6), np.zeros((6, 3)))
    tau_arm = gravity_torques(dh, q, LINKS, range(6))
    tau_payload = gravity_torques(dh, q, massless.with_payload(*payload), range(6))
    tau_both = gravity_torques(dh, q, LINKS.with_payload(*payload), range(6))
    np.testing.assert_allclose(tau_both, tau_arm + tau_payload, atol=1e-9)
    # the payload's point about joint 2: its position from the flange pose, lever times weight
    frames = base_from_frames(dh, q)
    point = tcp_position(dh, q, payload[1])
    z1, o1 = frames[:, 1, :3, 2], frames[:, 1, :3, 3]
    expected = np.einsum("ni,ni->n", z1, np.cross(point - o1, [0, 0, -payload[0] * G_MS2])) * 1e-3
    np.testing.assert_allclose(tau_payload[:, 1], expected, atol=1e-9)


def test_the_ur10s_load_bearing_joints_are_shoulder_and_elbow(rng):
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    assert load_bearing_joints(ur10(), q, LINKS) == (1, 2)


def test_link_angles_add_each_terms_deflection_on_its_joint(rng):
    dh, q = ur10(), rng.uniform(-np.pi, np.pi, (7, 6))
    terms = JointTerms(
        [Term(1, "compliance_urad_per_Nm"), Term(2, "sin1_deg"), Term(2, "cos2_deg")], dh, LINKS
    )
    c = np.array([15.0, 1e-3, -2e-3])
    q_link = terms.link_angles(q, c, terms.basis(q))
    expected = q.copy()
    expected[:, 1] += 1e-6 * 15.0 * gravity_torques(dh, q, LINKS, [1])[:, 0]
    expected[:, 2] += 1e-3 * np.sin(q[:, 2]) - 2e-3 * np.cos(2 * q[:, 2])
    np.testing.assert_allclose(q_link, expected, atol=1e-15)


def test_tcp_jacobian_by_the_terms_matches_finite_differences(rng):
    dh, q = ur10(), rng.uniform(-np.pi, np.pi, (9, 6))
    groups = [compliance_group(1), compliance_group(2)] + [
        harmonic_group(j, h) for j in range(6) for h in (1, 2)
    ]
    terms = JointTerms([t for g in groups for t in g.terms], dh, LINKS)
    basis, tool = terms.basis(q), np.array([5.0, -3.0, 100.0])
    c = rng.normal(0, 1e-3, len(terms)) * np.where(terms.prior_sigma() > 1, 1e4, 1.0)
    p, _, jac = terms.tcp_jacobian(dh, q, tool, c, basis)
    np.testing.assert_allclose(p, tcp_position(dh, terms.link_angles(q, c, basis), tool))
    h = 1e-6
    for k in range(len(terms)):
        e = np.zeros(len(terms))
        e[k] = h
        fd = [tcp_position(dh, terms.link_angles(q, c + s * e, basis), tool) for s in (1, -1)]
        np.testing.assert_allclose(jac[:, :, k], (fd[0] - fd[1]) / (2 * h), atol=1e-6, err_msg=terms.names[k])


def test_a_compliance_without_masses_is_refused():
    with pytest.raises(ValueError, match="link masses"):
        JointTerms([Term(1, "compliance_urad_per_Nm")], ur10(), None)


def test_the_turn_gap_is_the_widest_arc_no_row_visits():
    """Joint 1 on a whole turn (every 10 deg), joint 2 on an arc of 260 deg, joint 3 on an arc of 40
    deg across the +-180 deg seam, the rest still: the gaps are 10, 100, 320 and 360 deg."""
    q = np.zeros((37, 6))
    q[:, 0] = np.linspace(-180, 180, 37)
    q[:, 1] = np.linspace(-80, 180, 37)
    q[:, 2] = np.concatenate([np.linspace(150, 180, 19), np.linspace(-180, -170, 18)])
    np.testing.assert_allclose(np.degrees(turn_gap(np.radians(q))), [10, 100, 320, 360, 360, 360], atol=1e-9)
    assert whole_turn_joints(np.radians(q)) == (0,)
