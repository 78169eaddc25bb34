import pytest

from aerotrack.config import Config, config_to_dict, dumps_config, load_config
from aerotrack.errors import ConfigError


def test_defaults_round_trip(tmp_path):
    cfg = Config()
    p = tmp_path / "c.toml"
    p.write_text(dumps_config(cfg))
    assert load_config(p) == cfg


def test_override_changes_value_and_round_trips(tmp_path):
    cfg = load_config(None, ["detection.window_s=2.5", "association.max_speed_mps=30"])
    assert cfg.detection.window_s == 2.5
    assert cfg.association.max_speed_mps == 30.0
    p = tmp_path / "c.toml"
    p.write_text(dumps_config(cfg))
    assert config_to_dict(load_config(p)) == config_to_dict(cfg)


@pytest.mark.parametrize("bad", ["nosection.x=1", "detection.nokey=1", "detection.window_s=abc",
                                 "detection.window_s", "window_s=3"])
def test_bad_overrides_are_config_errors(bad):
    with pytest.raises(ConfigError):
        load_config(None, [bad])


def test_bad_toml_names_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[detection\nwindow_s = 1")
    with pytest.raises(ConfigError, match="bad.toml"):
        load_config(p)


def test_misplaced_and_misspelt_keys_are_named_helpfully(tmp_path):
    """A key above every section was called an unknown section, and a misspelt key listed ~90
    names without saying which one was meant."""
    top = tmp_path / "top.toml"
    top.write_text("threshold_sigma = 7.0\n")
    with pytest.raises(ConfigError, match=r"outside any \[section\]; it belongs under \[detection\]"):
        load_config(top)
    with pytest.raises(ConfigError, match=r"did you mean detection\.threshold_sigma"):
        load_config(None, ["detection.treshold_sigma=6"])
    with pytest.raises(ConfigError, match=r"did you mean \[detection\]"):
        load_config(None, ["detections.threshold_sigma=6"])


def test_configs_built_in_python_are_checked_like_files():
    """persist="false" turned persistence on (a non-empty string is true); a dict config failed
    with an AttributeError."""
    import dataclasses

    from aerotrack import pipeline
    from aerotrack.config import Config, as_config

    base = Config()
    bad = dataclasses.replace(base, detection=dataclasses.replace(base.detection, persist="false"))
    with pytest.raises(ConfigError, match="detection.persist: expected bool"):
        pipeline.check_config(bad)
    bad = dataclasses.replace(base, detection=dataclasses.replace(base.detection, window_s="3"))
    with pytest.raises(ConfigError, match="detection.window_s: expected float"):
        pipeline.Pipeline(bad, 30.0)
    with pytest.raises(ConfigError, match="expected an aerotrack Config"):
        as_config(["detection.persist=true"])
    assert as_config({"detection": {"persist": True}}).detection.persist is True
    assert as_config(None) == base
    ok = dataclasses.replace(base, association=dataclasses.replace(base.association, window_s=2))
    assert as_config(ok) is ok  # an int where a float goes is fine
