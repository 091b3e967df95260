"""The daemon's TOML configuration: embedded defaults, overrides, refusals naming the key."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from conftest import STREAMID

from streamid.daemon.config import DaemonConfig, StreamConfig, config_from_mapping, load_config
from streamid.errors import ConfigError


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "daemon.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_no_file_gives_the_embedded_defaults() -> None:
    c = load_config(None)
    assert c == DaemonConfig()
    assert c.discover and c.streams == ()
    s = c.for_stream("anything")
    assert s.cold_generations == 400 and s.warm_generations == 30 and s.validation_fraction == 0.3
    assert s.window_params().samples(5_000_000) == (2000, 200)  # 10 s window every 1 s at 200 Hz
    assert s.coea_config(cold=False).generations == 30


def test_full_file_with_overrides(tmp_path: Path) -> None:
    p = write(
        tmp_path,
        """
[daemon]
streams = ["bench1", "bench2"]
status_every_s = 0.5
workers = 2

[defaults]
window_samples = 1000
update_every_samples = 100
neurons = 8

[streams.bench1]
window_s = 0.5
update_every_s = 1
outputs = ["force"]
output = "force"

[streams.bench1.engine]
de_f = 0.5
centre_bounds = [-2, 2]
""",
    )
    c = load_config(p)
    assert c.streams == ("bench1", "bench2") and not c.discover and c.workers == 2
    b1, b2 = c.for_stream("bench1"), c.for_stream("bench2")
    assert b2 == c.defaults and b2.window_samples == 1000 and b2.neurons == 8
    # seconds given in the override replace the inherited sample counts
    assert (b1.window_s, b1.window_samples, b1.update_every_s, b1.update_every_samples) == (0.5, None, 1.0, None)
    assert b1.neurons == 8 and b1.outputs == ("force",)
    eng = b1.coea_config(cold=True)
    assert eng.de_f == 0.5 and eng.centre_bounds == (-2.0, 2.0) and eng.neurons == 8


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[defaults]\nwindw_s = 1.0", r"unknown key 'defaults\.windw_s'.*accepted keys.*window_s"),
        ("[daemon]\nstream = ['a']", r"unknown key 'daemon\.stream'.*streams"),
        ("[streams.a]\nneuron = 3", r"unknown key 'streams\.a\.neuron'"),
        ("[streams.a.engine]\ngenerations = 3", r"unknown key 'streams\.a\.engine\.generations'.*de_f"),
        ("[streams.a.engine]\nfeedthrough_test = true",
         r"\[streams\.a\.engine\]: CoEAConfig\.feedthrough_test was retired in issue 37: use direct_terms = \"test\""),
        ("[streams.a.engine]\nworkers = 2", r"CoEAConfig\.workers was retired .*identify\(\.\.\., workers=N\)"),
        ("verbose = true", r"unknown key 'verbose'.*daemon, defaults, streams"),
        ("[defaults]\nwindow_s = 'ten'", r"defaults\.window_s must be a number of seconds > 0; got 'ten' \(str\)"),
        ("[defaults]\nneurons = 4.5", r"defaults\.neurons must be an integer >= 1; got 4\.5 \(float\)"),
        ("[defaults]\nneurons = true", r"defaults\.neurons must be an integer"),
        ("[daemon]\nworkers = '2'", r"daemon\.workers must be an integer in \[1, 64\]; got '2'"),
        ("[daemon]\ndiscover = 1", r"daemon\.discover must be true or false; got 1"),
        ("[defaults]\ninputs = 'u'", r"defaults\.inputs must be a list of signal names; got 'u'"),
        ("[defaults]\nvalidation_fraction = 0.95", r"validation_fraction must be a number in \[0\.05, 0\.9\]; got 0\.95"),
        ("[defaults]\nwindow_s = -1.0", r"window_s must be a finite number of seconds > 0; got -1\.0"),
        ("[defaults]\nneurons = 0", r"CoEAConfig\.neurons must be an integer"),
        ("[defaults]\nwindow_s = 1.0\nwindow_samples = 100", r"at most one of window_s .* or window_samples"),
        ("[streams.'bad/name']\nneurons = 3", r"streams\.bad/name.*stream name"),
        ("[daemon]\ndiscover = false", r"daemon\.streams must name at least one stream"),
        ("[defaults]\noutputs = ['y']\noutput = 'z'", r"output must be one of outputs \['y'\]; got 'z'"),
    ],
)
def test_bad_files_are_refused_naming_the_key(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as info:
        load_config(write(tmp_path, text))
    assert str(tmp_path / "daemon.toml") in str(info.value)  # the file is named too


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="readable UTF-8 TOML"):
        load_config(tmp_path / "missing.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[daemon\nworkers = 1"))


def test_with_streams_turns_discovery_off() -> None:
    c = config_from_mapping({}).with_streams(("a", "a", "b"))
    assert c.streams == ("a", "b") and not c.discover
    with pytest.raises(ConfigError, match="stream names"):
        DaemonConfig(streams=("no/slash",))


def test_stream_config_round_trips_through_to_dict() -> None:
    s = StreamConfig(window_s=2.0, inputs=("a",), engine=(("de_f", 0.5),))
    d = s.to_dict()
    assert d["window_s"] == 2.0 and d["inputs"] == ["a"] and d["engine"] == {"de_f": 0.5}
    again = config_from_mapping({"defaults": d}).defaults
    assert again == s


def test_cli_refuses_a_bad_config_at_start(tmp_path: Path) -> None:
    p = write(tmp_path, "[defaults]\nwarm_generation = 20\n")
    out = subprocess.run([*STREAMID, "daemon", "--config", str(p), "--no-rerun"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2
    assert "unknown key 'defaults.warm_generation'" in out.stderr and "warm_generations" in out.stderr
    ok = subprocess.run([*STREAMID, "daemon", "--print-config"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and "cold_generations = 400" in ok.stdout


def test_print_config_is_every_effective_setting_as_toml_read_back_the_same(tmp_path: Path) -> None:
    import sys

    from streamid.daemon.config import to_toml
    from streamid.online.rows import search_row_bound

    src = tmp_path / "c.toml"
    src.write_text('[daemon]\nstreams = ["a", "b"]\nworkers = 2\n[streams.a]\nwindow_s = 0.5\n'
                   '[streams.a.engine]\nde_f = 0.5\nselection = "fr_est"\n')
    config = load_config(src)
    text = to_toml(config)
    for key in ("[daemon]", "workers = 2", "[defaults]", "window_s = 10.0", "update_every_s = 1.0",
                "[defaults.engine]", "de_f = 0.6", "[streams.a]", "window_s = 0.5", "[streams.a.engine]",
                'selection = "fr_est"', "retain_memory = true"):
        assert key in text, key
    again = tmp_path / "again.toml"
    again.write_text(text)
    reread = load_config(again)
    assert reread.workers == 2 and reread.streams == ("a", "b")
    assert reread.for_stream("a").coea_config(cold=True) == config.for_stream("a").coea_config(cold=True)
    assert reread.for_stream("a").window_params() == config.for_stream("a").window_params()
    for name in ("a", "b"):  # the search's row bound too (an engine key online): unset, the default bound
        before, after = (dict(c.for_stream(name).engine) for c in (config, reread))
        assert "search_rows" not in after and search_row_bound(10, 10, 10, 1, after) == 4096
        assert search_row_bound(10, 10, 10, 2, after) == search_row_bound(10, 10, 10, 2, before) == 128 * 41
    assert "# search_rows: the default bound, max(4096, 128 (neurons + D + 1)) rows" in text
    assert to_toml(reread) == text  # a fixed point
    out = subprocess.run([sys.executable, "-m", "streamid", "daemon", "--config", str(src), "--print-config"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout == text, out.stderr


def test_a_row_bound_set_for_a_stream_is_printed_and_read_back() -> None:
    import tomllib

    from streamid.daemon.config import config_from_mapping, to_toml

    cfg = config_from_mapping({"streams": {"fast": {"engine": {"search_rows": 0}}, "slow": {}}})
    back = config_from_mapping(tomllib.loads(to_toml(cfg)))
    assert dict(back.for_stream("fast").engine)["search_rows"] == 0  # every row, as set
    assert "search_rows" not in dict(back.for_stream("slow").engine)  # the default bound, as before


def test_the_refresh_policy_is_a_table_per_stream_and_round_trips() -> None:
    import tomllib

    from streamid.daemon.config import config_from_mapping, to_toml
    from streamid.online import RefreshPolicy

    cfg = config_from_mapping({"defaults": {"refresh": {"enabled": False}},
                               "streams": {"a": {"refresh": {"enabled": True, "min_every": 2}}}})
    assert cfg.for_stream("b").refresh == RefreshPolicy(enabled=False)
    assert cfg.for_stream("a").refresh == RefreshPolicy(enabled=True, min_every=2)  # over the defaults' table
    back = config_from_mapping(tomllib.loads(to_toml(cfg)))
    assert back.for_stream("a").refresh == cfg.for_stream("a").refresh and to_toml(back) == to_toml(cfg)
    for table, text in (({"enabeld": False}, r"unknown key 'defaults.refresh.enabeld'.*enabled, max_every"),
                        ({"enabled": "no"}, r"\[defaults.refresh\]: RefreshPolicy.enabled must be true or false; got 'no'"),
                        ({"min_every": 8, "max_every": 4}, r"max_every must be >= min_every \(8\); got 4")):
        with pytest.raises(ConfigError, match=text):
            config_from_mapping({"defaults": {"refresh": table}}, "x.toml")
