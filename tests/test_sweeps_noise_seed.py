"""``volcomp sweeps``: the tracker pose and noise seed is derived from ``--seed`` unless ``--seed-noise`` is given
(issue 26): child 3 of ``SeedSequence(seed)`` (children 0-2 are the simulator's streams of the same seed), printed
and written in the file, so a run is reproduced from its seed alone or from the printed noise seed."""
from __future__ import annotations

import re

import numpy as np
import pytest

from compensation.app.cli import main
from provenance import text_and_provenance


def _noise_seed(text: str) -> int:
    return int(re.search(r"seed_noise: (\d+)", text).group(1))


@pytest.mark.parametrize("machine", [[], ["--machine", "mill-xyz"]], ids=["grinder", "mill-xyz"])
def test_noise_seed_follows_the_seed(tmp_path, capsys, machine):
    def sweeps(name, *opts):
        assert main(["sweeps", *machine, *opts, "--out", str(tmp_path / name)]) == 0
        return text_and_provenance(tmp_path / name).encode(), capsys.readouterr().out

    a, out_a = sweeps("a.csv", "--seed", "3")
    want = int(np.random.SeedSequence(3).spawn(4)[3].generate_state(1)[0])   # independent of the code's helper
    assert _noise_seed(a.decode()) == want and f"noise seed {want} (derived from --seed 3" in out_a
    b, _ = sweeps("b.csv", "--seed", "3")
    assert a == b                                                             # the same seed: the same file
    c, out_c = sweeps("c.csv", "--seed", "3", "--seed-noise", str(want))
    assert c == a and f"noise seed {want} (--seed-noise)" in out_c            # the printed seed reproduces it
    d, _ = sweeps("d.csv", "--seed", "4")
    assert _noise_seed(d.decode()) != want                                    # another seed: another noise
    e, _ = sweeps("e.csv", "--seed", "3", "--seed-noise", "0")
    assert _noise_seed(e.decode()) == 0 and e != a                            # given: used as given


def test_truth_file_without_noise_seed_uses_zero(tmp_path, capsys):
    from errormap.machine import load_machine
    from errormap.chain_truth import make_chain_truth
    el = make_chain_truth(load_machine(), 1).elements.save(tmp_path / "el.json")
    assert main(["sweeps", "--truth", str(el), "--out", str(tmp_path / "s.csv")]) == 0
    assert "noise seed 0 (default with --truth)" in capsys.readouterr().out
    assert _noise_seed(text_and_provenance(tmp_path / "s.csv")) == 0
