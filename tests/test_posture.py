"""Start postures (find_equilibrium) and task files: real postures of real bodies, and bad input."""

import dataclasses
import pathlib

import jax
import numpy as np
import pytest

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.strategy import posture
from jaxhumanoid.strategy.posture import MarginSpec, find_equilibrium, margins
from jaxhumanoid.strategy.taskfile import load_task_file, task_files
from jaxhumanoid.studies import load_spec
from jaxhumanoid.studies.run import perturbed_contact, perturbed_start

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"
ROOT = EXAMPLES.parent
DEG = np.pi / 180
ZERO = MarginSpec(load_min=0.0, friction_margin=0.0, cop_margin=0.0, clearance=-1.0)  # (5) itself


@pytest.mark.parametrize("key", ["T1", "T3"])
def test_the_paper_start_postures_are_their_own_equilibria(key):
    task = tasks.get_task(key)
    eq = find_equilibrium(PlanarChain.humanoid(), task.start, task.active)
    assert eq.moved < 1e-9 and eq.nominal.ok and eq.relaxed.ok
    assert 0.1 <= eq.nominal.load <= 1.0  # the foot carries part of the weight, the contacts the rest
    assert np.all(eq.nominal.foot >= 0)  # the five products of (5)
    assert np.max(np.abs(eq.q_relaxed - eq.q)) < 0.05  # re-seated by millimetres, not a new posture


def test_a_guess_off_equilibrium_is_moved_to_one_that_keeps_the_foot_steady():
    model, task = PlanarChain.humanoid(), tasks.get_task("T1")
    guess = task.start + np.array([0.3, -0.2, 0.1, 0.2, 0.1])
    spec = MarginSpec()
    assert not margins(model, guess, task.active, spec=spec).ok  # the check can fail
    eq = find_equilibrium(model, guess, task.active, spec=spec)
    assert eq.nominal.ok and eq.moved > 0.01
    m = eq.nominal
    assert m.load >= spec.load_min - 1e-6 and m.friction <= 1 - spec.friction_margin + 1e-6
    foot = FootParams.paper()
    assert -foot.a0f + spec.cop_margin - 1e-6 <= m.cop <= foot.a0b - spec.cop_margin + 1e-6


def test_reseating_for_a_softer_law_lifts_a_lightly_loaded_contact_instead_of_pressing_it():
    body, foot, task = PlanarChain.humanoid(), FootParams.paper(), tasks.get_task("T1")
    nominal, relaxed = ContactParams.nominal(), ContactParams.relaxed()
    rows = np.asarray(task.active) - 1

    def normal(law, q):
        return np.asarray(ct.normal_force(law, np.asarray(kin.contact_gaps(body, foot, q))[rows]))

    # the prone start with its hand asked to carry 0.5 N: lifted off to where it carries LIGHT_CONTACT
    asked = normal(nominal, task.start) * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 0.5])
    q = posture.seat_with_forces(body, foot, nominal, task.start, task.active, asked)
    np.testing.assert_allclose(normal(nominal, q), np.maximum(asked, posture.LIGHT_CONTACT), rtol=1e-6)
    assert normal(relaxed, q)[2] > 50.0  # the relaxed law reaches further: the hand would take load
    p = tr.default_params(task, contact=nominal)
    q_rel, dgap = posture.reseat_for_contact(p, q, task.active, relaxed)
    f_rel = normal(relaxed, q_rel)
    np.testing.assert_allclose(f_rel, normal(nominal, q), rtol=1e-6)
    assert 0.01 < dgap < 0.06
    # the posture carries what it carried: the same loads, hence nearly the same torques
    u_nom, u_rel = (
        margins(body, q, task.active, contact=nominal).u,
        margins(body, q_rel, task.active, contact=relaxed).u,
    )
    np.testing.assert_allclose(u_rel, u_nom, atol=0.05 * np.abs(u_nom).max())
    assert np.abs(margins(body, q, task.active, contact=relaxed).u - u_nom).max() > 10.0  # mutation: not re-seated


def test_reseating_keeps_the_foot_steady_where_the_least_motion_would_tip_it():
    """Draw 9 of T1 in the robustness study: the start carries 0.1 M g on the foot. The least
    motion that seats it for the relaxed law moves the ankle torque by ~3 N m and the centre of
    pressure off the sole (the plain seat breaks (5)); the reseat with the ankle row keeps (5)."""
    spec = load_spec(ROOT / "examples" / "studies" / "robustness.toml")
    case = next(c for c in spec.cases if c.task == "T1" and c.draw == 9 and c.solver == "ipopt")
    law = perturbed_contact(None, dict(case.factors))
    task, _ = perturbed_start(case, tasks.get_task("T1"), PlanarChain.humanoid(), law, None)
    p = tr.default_params(task, contact=law)
    relaxed = ContactParams.relaxed()
    q = np.asarray(task.start)
    idx = np.asarray(task.active) - 1
    f_nom = np.asarray(ct.normal_force(law, np.asarray(kin.contact_gaps(p.model, p.foot, q))[idx]))
    plain = posture.seat_with_forces(p.model, p.foot, relaxed, q, task.active, f_nom)
    assert posture.margins(p.model, q, task.active, law, spec=ZERO).ok
    assert not posture.margins(p.model, plain, task.active, relaxed, spec=ZERO).ok  # the failure it mends
    q_rel, dgap = posture.reseat_for_contact(p, q, task.active, relaxed)
    m = posture.margins(p.model, q_rel, task.active, relaxed, spec=ZERO)
    assert m.ok and np.all(m.foot > 1.0) and dgap < 0.05
    forces = np.asarray(ct.normal_force(relaxed, np.asarray(kin.contact_gaps(p.model, p.foot, q_rel))[idx]))
    np.testing.assert_allclose(forces, f_nom, rtol=0.1, atol=2.0)


def test_the_compiled_gaps_and_their_jacobian_have_the_bits_of_op_by_op_evaluation():
    """The seating loops run the gaps and their Jacobian compiled; the postures they seat start every
    2S solve, whose path depends on their last bits, so compiled and op-by-op must agree exactly."""
    model, foot = PlanarChain.humanoid(), FootParams.paper()
    rng = np.random.default_rng(0)
    postures = [tasks.get_task(k).start for k in ("T1", "T2", "T3", "T4")]
    postures += [tasks.get_task("T1").start + rng.normal(0.0, 0.3, model.n) for _ in range(8)]
    jacobian = jax.jacfwd(lambda q: kin.contact_gaps(model, foot, q))
    for q in postures:
        assert np.array_equal(posture._gaps(model, foot, q), kin.contact_gaps(model, foot, q))
        assert np.array_equal(posture._gaps_jacobian(model, foot, q), jacobian(q))
    longer = dataclasses.replace(model, a=1.1 * np.asarray(model.a), c=1.1 * np.asarray(model.c))
    for q in postures[:4]:  # another body: the same program, other arguments
        assert np.array_equal(posture._gaps(longer, foot, q), kin.contact_gaps(longer, foot, q))


def test_no_equilibrium_on_a_foot_too_short_is_a_clear_error():
    tiny = dataclasses.replace(FootParams.paper(), a0f=0.01, a0b=0.01)
    task = tasks.get_task("T3")
    with pytest.raises(ValueError, match="find_equilibrium: no static equilibrium"):
        find_equilibrium(PlanarChain.humanoid(), task.start, task.active, foot=tiny)


def test_bad_guess_is_rejected_by_name():
    with pytest.raises(ValueError, match="q_guess"):
        find_equilibrium(PlanarChain.humanoid(), np.zeros(3), (1,))
    with pytest.raises(ValueError, match="active"):
        find_equilibrium(PlanarChain.humanoid(), tasks.STANDING, (6,))


@pytest.mark.parametrize("path", task_files(EXAMPLES), ids=lambda p: p.stem)
def test_example_task_files_load_and_pose_equilibria(path):
    tf = load_task_file(path)
    assert tf.task.n == tf.model.n and tf.keywords["N"] >= 10
    contact = tf.contact
    if "soft" not in path.stem:  # that one is moved to its equilibrium when it is solved
        assert margins(tf.model, tf.task.start, tf.task.active, contact=contact, foot=tf.foot).ok, path.name


@pytest.mark.parametrize(
    "text, field",
    [
        (
            'name = "x"\n[task]\nstart = [1, 0]\ngoal = [1, 0]\nactive = [2]\n[body]\na = [-0.4, 0.5]\n'
            "c = [0.1, 0.1]\nm = [1, 1]\ninertia = [0.1, 0.1]\n",
            "PlanarChain.a",
        ),
        ('name = "x"\n[task]\nstart = [1, 0, 0]\ngoal = [1, 0, 0, 0, 0]\nactive = [2]\n', "start"),
        ('name = "x"\n[task]\nstart_deg = [1, 0, 0, 0, 0]\ngoal_deg = [1, 0, 0, 0, 0]\nactive = [9]\n', "active"),
        ('name = "x"\n[tsak]\n', "tsak"),
        ('name = "x"\n[task]\nstart = [1]\n[weights]\nw_x = 1\n', "w_x"),
        ('name = "x"\n[body]\npreset = "robot"\n[task]\n', "preset"),
        ('name = "x\n', "TOML"),
    ],
)
def test_bad_task_files_name_the_field(tmp_path, text, field):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=field) as err:
        load_task_file(path)
    assert "bad.toml" in str(err.value)


def test_task_files_of_a_folder_leave_study_specs_out():
    names = [p.name for p in task_files(EXAMPLES)]
    assert "bow_3link.toml" in names and [p.name for p in task_files(EXAMPLES / "paper")][0] == "T1.toml"
    assert "sweep_small.toml" not in names and (EXAMPLES / "sweep_small.toml").exists()
    assert task_files(EXAMPLES / "no-such-folder") == []
