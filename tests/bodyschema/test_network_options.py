"""The sensor networks' training settings as one value (bodyschema.network_options)."""

from __future__ import annotations

import pickle

import pytest

from bodyschema.network_options import NETWORK_FIELDS, NetworkOptions, network_options, split_network_options


def test_the_defaults_are_the_training_loops_and_only_changed_fields_are_keywords():
    opts = NetworkOptions()
    assert (opts.hidden, opts.epochs, opts.batch_size, opts.lr, opts.max_epochs) == (
        (32, 32, 32),
        None,
        64,
        1e-2,
        200,
    )
    assert opts.keywords() == {}
    changed = NetworkOptions(epochs=5, seed=3, hidden=[16, 16])
    assert changed.hidden == (16, 16)
    assert changed.keywords() == {"hidden": (16, 16), "epochs": 5, "seed": 3}
    assert pickle.loads(pickle.dumps(changed)) == changed  # it travels into a cluster task as it is


def test_keywords_replace_fields_and_a_name_that_is_no_field_is_refused():
    base = NetworkOptions(seed=7, max_epochs=40)
    assert network_options(base, epochs=2) == NetworkOptions(seed=7, max_epochs=40, epochs=2)
    assert network_options() == NetworkOptions()
    with pytest.raises(TypeError, match="warmth"):
        network_options(warmth=1)
    kw = {"epochs": 2, "lam": 0.2, "warm_start": None}
    assert split_network_options(kw, base) == NetworkOptions(seed=7, max_epochs=40, epochs=2)
    assert kw == {"lam": 0.2, "warm_start": None}
    assert "plateau_tol" in NETWORK_FIELDS and "warm_start" not in NETWORK_FIELDS
