"""The one model factory and the one answer path (issue 22): OnlineTrackModel.from_settings and online.answer.

Both must be the previous constructions exactly: the model the track node and
``clm replay`` built by hand, decoded, processed and encoded by hand, gives
bit for bit the bytes that ``from_settings`` + ``answer`` give, on a fixed
stream with refusals of several causes, a jump and a new stream.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from clm_core.errors import ParameterError
from clm_core.io.errors import MessageError
from clm_core.io.messages import (
    encode_sleeper_response,
    encode_wheel_loads,
    encode_wheel_rail_response,
    sleeper_fields,
    wheel_fields,
)
from clm_core.online import (
    MODEL_SETTINGS,
    Answer,
    InputPolicy,
    OnlineTrackModel,
    Reason,
    Rejected,
    WheelFrame,
    answer,
    frame_from_cdr,
    model_params,
)
from clm_core.params import load_model
from clm_core.settings import ONLINE_POLICY, setting

MS = 1_000_000
T0 = 1_796_150_165_843_913_423

#: Node-style settings: ROS stand-ins for "unset" (lead_sleepers -1, params_file "", NaN overrides), one override.
NODE = {"track": "mevergnies", "soil": "mevergnies", "model": "clm", "params_file": "", "dt": 1e-4,
        "n_sleepers": 41, "elements_per_bay": 2, "lead_sleepers": -1, "max_gap": 0.5, "accept_new_wheels": False,
        "track.kb": 60e6, "soil.kf": math.nan, "max_wheel_force": 4e5, "resync_confirm": 2,
        "diagnostics_period": 0.5}  # (not a model setting: ignored)


def _raws() -> list[bytes]:
    """A fixed stream: 40 good frames of two wheels, then refusals (tensile, undecodable, jump) and a new stream."""
    out = []
    for k in range(40):
        t = k * 1e-3
        out.append(encode_wheel_loads(T0 + k * MS, "v", [3, 4], [20.0 + 40 * t, 17.0 + 40 * t],
                                      [90e3 + 5e3 * math.sin(60 * t), 88e3]))
    out.append(encode_wheel_loads(T0 + 40 * MS, "v", [3, 4], [21.6, 18.6], [90e3, -5e3]))  # tensile
    out.append(b"\x00\x01\x00\x00garbage")  # undecodable
    out.append(encode_wheel_loads(T0 + 41 * MS, "v", [3, 4], [21.64, 18.64], [9e5, 8e4]))  # implausible force
    for k in range(3):  # a new timeline (a jump of 10 s): confirmed by the second (resync_confirm 2)
        out.append(encode_wheel_loads(T0 + 10**10 + k * MS, "v", [3, 4], [50.0 + 0.04 * k, 47.0 + 0.04 * k],
                                      [85e3, 85e3]))
    return out


def _by_hand(raws: list[bytes], frame_id: str) -> tuple[OnlineTrackModel, list[tuple[bytes, bytes] | str]]:
    """What track_node.build_model/build_params and replay._chunk did before the factory and the answer path."""
    over = {"kb": 60e6}
    params = load_model("mevergnies", "mevergnies", "clm", over)
    model = OnlineTrackModel(params, dt=1e-4, n_sleepers=41, elements_per_bay=2, max_gap=0.5,
                             accept_new_wheels=False, lead_sleepers=None,
                             policy=InputPolicy.from_settings({n: NODE.get(n, setting(n).default)
                                                               for n in ONLINE_POLICY}))
    frames: list[WheelFrame] = []
    pre: list[Rejected | None] = []
    for raw in raws:
        try:
            frames.append(frame_from_cdr(raw))
            pre.append(None)
        except MessageError as exc:
            pre.append(model.reject(Reason.MALFORMED, str(exc)))
    it = iter(model.process_batch(frames))
    out: list[tuple[bytes, bytes] | str] = []
    for p in pre:
        r = next(it) if p is None else p
        if isinstance(r, Rejected):
            out.append(r.reason.value)
            continue
        s, w = sleeper_fields(r), wheel_fields(r)
        out.append((encode_sleeper_response(r.stamp_ns, frame_id, *s.values()),
                    encode_wheel_rail_response(r.stamp_ns, frame_id, *w.values())))
    return model, out


def _plain(results: list[Answer | Rejected]) -> list[tuple[bytes, bytes] | str]:
    return [r.reason.value if isinstance(r, Rejected) else (r.sleeper_response, r.wheel_rail_response)
            for r in results]


def test_factory_and_answer_path_give_the_previous_bytes_exactly() -> None:
    raws = _raws()
    ref_model, ref = _by_hand(raws, "track")
    model = OnlineTrackModel.from_settings(NODE)
    got = answer(model, raws, "track")
    assert _plain(got) == ref  # bytes equal, in order
    causes = [r for r in ref if isinstance(r, str)]
    assert causes == ["tensile", "malformed", "implausible_force", "stamp_jump"] and len(ref) - len(causes) == 42
    # the first frame starts the state, the second frame of the new timeline restarts it
    assert [i for i, r in enumerate(got) if isinstance(r, Answer) and r.response.resynced] == [0, 44]
    assert (model.stats.accepted, dict(model.stats.rejected), model.stats.steps) == (
        ref_model.stats.accepted, dict(ref_model.stats.rejected), ref_model.stats.steps)
    # in chunks of any size (the node's and replay's CHUNK), the same answers
    model2 = OnlineTrackModel.from_settings(NODE)
    chunked = [a for i in range(0, len(raws), 7) for a in answer(model2, raws[i:i + 7], "track", first=i + 1)]
    assert _plain(chunked) == ref


def test_a_malformed_message_is_refused_in_its_place_and_named() -> None:
    model = OnlineTrackModel.from_settings({"n_sleepers": 31})
    raws = [encode_wheel_loads(T0, "v", [0], [1.0], [1e5]), b"xx", encode_wheel_loads(T0 + MS, "v", [0], [1.04], [1e5])]
    out = answer(model, raws, topic="/train_0/wheel_loads", first=11)
    assert [type(r).__name__ for r in out] == ["Answer", "Rejected", "Answer"]
    assert str(out[1]).startswith("malformed: message 12 on /train_0/wheel_loads cannot be decoded (")
    assert model.stats.rejected[Reason.MALFORMED.value] == 1 and model.stats.accepted == 2
    assert answer(model, []) == [] and answer(model, [b""])[0].reason is Reason.MALFORMED  # type: ignore[union-attr]


def test_factory_carries_every_model_setting_and_renewed_keeps_them() -> None:
    """Every setting of MODEL_SETTINGS reaches the model (a non-default value of each), and a renewed model (a new
    stream) has them all, the same parameters, the same counters and a fresh state."""
    values: dict[str, Any] = {"dt": 2e-4, "n_sleepers": 51, "elements_per_bay": 3, "lead_sleepers": 12,
                              "max_gap": 0.25, "accept_new_wheels": True, "initial_state": "rest",
                              "max_wheel_force": 5e5, "max_wheel_position": 1e5, "max_wheel_speed": 100.0,
                              "max_response_force": 1e7, "max_response_displacement": 0.1, "resync_confirm": 4,
                              "max_wheels": 16}
    assert set(values) == set(MODEL_SETTINGS)
    for name, v in values.items():
        assert v != setting(name).default, name
    model = OnlineTrackModel.from_settings(values)
    assert model.settings == values
    assert model.sim.lead_sleepers == 12 and model.sim.elements_per_bay == 3 and model.sim.n_sleepers == 51
    model.process_batch([frame_from_cdr(encode_wheel_loads(T0, "v", [0], [1.0], [1e5]))])
    new = model.renewed()
    assert new.settings == values and new.params is model.params and new.stats is model.stats
    assert new.last_stamp_ns is None and model.last_stamp_ns == T0
    # defaults: the schema's
    assert OnlineTrackModel.from_settings().settings == {n: setting(n).default for n in MODEL_SETTINGS}


def test_every_setting_the_factory_reads_is_a_run_setting() -> None:
    """FACTORY_SETTINGS (what a node declares) are settings of the schema, each once; a mapping of all of them at
    their ROS values (stand-ins for unset) builds the default model."""
    from clm_core.online import FACTORY_SETTINGS, PARAMS_SETTINGS

    assert len(set(FACTORY_SETTINGS)) == len(FACTORY_SETTINGS)
    assert set(PARAMS_SETTINGS) | set(MODEL_SETTINGS) <= set(FACTORY_SETTINGS)
    ros = {name: setting(name).to_ros() for name in FACTORY_SETTINGS}
    model = OnlineTrackModel.from_settings(ros)
    assert model.settings == OnlineTrackModel.from_settings().settings
    assert model.params == load_model("mevergnies", "mevergnies", "clm")


def test_model_params_reads_presets_overrides_and_ros_stand_ins() -> None:
    ref = load_model("mevergnies", "mevergnies", "clm", {"kb": 60e6})
    assert model_params(NODE) == ref
    assert model_params({"model": "rigid", "track.kb": None}) == load_model("mevergnies", "mevergnies", "rigid")


@pytest.mark.parametrize(("values", "fragment"), [
    ({"dt": -1.0}, "dt = -1"),
    ({"n_sleepers": 3}, "n_sleepers = 3"),
    ({"initial_state": "moving"}, "initial_state = 'moving'"),
    ({"max_wheels": 0}, "max_wheels = 0"),
    ({"model": "foam"}, "model = 'foam'"),
    ({"track.kb": -5.0}, "kb"),
    ({"lead_sleepers": 2.5}, "lead_sleepers = 2.5"),
])
def test_factory_refuses_a_bad_setting_naming_it(values: dict[str, Any], fragment: str) -> None:
    with pytest.raises(ParameterError, match=fragment.replace("(", r"\(")):
        OnlineTrackModel.from_settings(values)


def test_answers_encode_lazily_and_once() -> None:
    model = OnlineTrackModel.from_settings({"n_sleepers": 31})
    (a,) = answer(model, [encode_wheel_loads(T0, "v", [2], [1.0], [1e5])], "rail")
    assert isinstance(a, Answer) and a.stamp_ns == T0
    assert a.sleeper_response is a.sleeper_response and a.wheel_rail_response is a.wheel_rail_response
    assert np.frombuffer(a.sleeper_response[:4], np.uint8).tolist() == [0, 1, 0, 0]  # CDR little-endian header
