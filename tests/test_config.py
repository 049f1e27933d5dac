"""Configuration TOML: defaults, validation errors, dump/load round trip."""

from __future__ import annotations

import pytest

from fgloc.config import Config, dump_config, load_config
from fgloc.errors import InputError


def test_defaults_dump_and_reload(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(dump_config(Config()))
    assert load_config(p) == Config()


def test_override_and_int_to_float(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("seed = 7\n[coarse]\ndoppler_min = 1\nicp_ranges = [8, 4.0]\n")
    cfg = load_config(p)
    assert cfg.seed == 7
    assert cfg.coarse.doppler_min == 1.0 and isinstance(cfg.coarse.doppler_min, float)
    assert cfg.coarse.icp_ranges == [8.0, 4.0]


@pytest.mark.parametrize(
    "text, field",
    [
        ("[coarse]\nlambda = 0.3\n", "coarse.lambda"),
        ("[coarse]\ndoppler_min = 'fast'\n", "coarse.doppler_min"),
        ("seed = 1.5\n", "seed"),
        ("[map]\nroad_classes = [2, 'x']\n", "map.road_classes"),
        ("bogus = 1\n", "bogus"),
        ("[smoothing]\nbatch_steps = 0\n", "smoothing"),
    ],
    ids=["unknown-key", "wrong-type", "float-for-int", "bad-list-item", "unknown-top",
         "out-of-range"],
)
def test_bad_config_names_the_key(tmp_path, text, field):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(InputError) as ei:
        load_config(p)
    assert ei.value.field == field
    assert str(p) in str(ei.value)


def test_toml_syntax_error(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("seed = = 1\n")
    with pytest.raises(InputError, match="invalid TOML"):
        load_config(p)
