# SPDX-License-Identifier: Apache-2.0
"""The bad-input corpus (test/corpus/, made by scripts/make_corpus.py): one test per file.

Every file must give ``error: <file>: <what, where>`` on stderr, exit status 2, no
traceback and no output file. A new corpus file without an entry here fails
``test_every_corpus_file_has_a_case``.
"""

from pathlib import Path

import pytest

from mr_ident.cli import main

ROOT = Path(__file__).resolve().parents[1]
CORPUS = ROOT / "test" / "corpus"
PAPER = ROOT / "config" / "paper_example.yaml"

#: file -> text the error must hold (what went wrong and where).
CASES = {
    "csv_nan.csv": "line 43, column 't': nan",
    "csv_inf.csv": "line 101, column 'u': inf",
    "csv_text.csv": "line 8, column 'r': 'abc' is not a number",
    "csv_missing_column.csv": "missing column 'u'",
    "csv_unequal_lengths.csv": "line 152 has 3 values, the header names 4 columns",
    "csv_zero_rows.csv": "empty file",
    "csv_header_only.csv": "no data rows after the header",
    "npz_wrong_shape.npz": "array 'r' must have shape (N,) or (N, channels) with N > 0, "
    "got (50, 3, 2)",
    "npz_empty_arrays.npz": "array 'r' must have shape (N,) or (N, channels) with N > 0, got (0,)",
    "npz_non_integer_ratio.npz": "ratio must be one integer >= 1, got 2.5",
    "npz_unequal_lengths.npz": "r, u, y have unequal lengths {'r': 300, 'u': 297, 'y': 300}",
    "npz_text_array.npz": "array 'r' must be numeric",
    "model_non_numeric.yaml": "plant.num[2] must be a finite number, got '29850.0x'",
    "model_unstable.yaml": "closed loop is not stable",
    "model_ratio_zero.yaml": "ratio must be an integer >= 1, got 0",
    "model_unknown_key.yaml": "unknown key(s) ['noise_sdt']",
    "model_not_yaml.yaml": "not valid YAML: line 3, column 1",
    "mcap_truncated_magic.mcap": "not an MCAP file",
    "mcap_truncated_header.mcap": "the file ends inside a record after byte 8",
    "mcap_truncated_first_chunk.mcap": "no channel could be read "
    "(the file ends inside a record after byte",
    "mcap_truncated_late.mcap": "cut short: recovered 25 messages",
    "mcap_wrong_schema.mcap": "topic '/reference' has schema 'std_msgs/msg/String'",
    "mcap_non_monotonic.mcap": "index went back from 240 to 127 with other samples",
    "mcap_missing_topic.mcap": "topic(s) ['output'] not in the recording",
    "mcap_not_mcap.mcap": "not an MCAP file (bad magic)",
}


def _command(path: Path, out: Path) -> list[str]:
    kind = path.name.split("_", 1)[0]
    if kind in ("csv", "npz"):
        return [
            "identify",
            str(path),
            "--ratio",
            "3",
            "--fs-high",
            "240",
            "--out",
            str(out / "result.npz"),
            "--plot",
            str(out / "bode.png"),
        ]
    if kind == "model":
        return ["simulate", str(path), "--duration", "1", "--out", str(out / "data.csv")]
    return ["replay", str(path), "--out", str(out / "result.npz"), "--plot", str(out / "bode.png")]


def test_every_corpus_file_has_a_case():
    assert sorted(p.name for p in CORPUS.iterdir()) == sorted(CASES)


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_file_is_an_error_naming_what_and_where(name, tmp_path, capsys):
    path = CORPUS / name
    out = tmp_path / "out"
    out.mkdir()
    code = main(_command(path, out))  # an uncaught exception (a traceback) fails the test
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}"), err
    assert CASES[name] in err, err
    assert list(out.iterdir()) == [], "a partial output was left behind"


def test_diagnose_reads_what_a_cut_recording_holds_and_says_so(tmp_path, capsys):
    """A recording cut short is still data: diagnose warns, uses its finished chunks."""
    code = main(
        [
            "diagnose",
            str(PAPER),
            str(CORPUS / "mcap_truncated_late.mcap"),
            "--json",
            str(tmp_path / "d.json"),
        ]
    )
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "is truncated" in err and "using the 960 samples read" in err
    assert out.startswith("cause: none")
