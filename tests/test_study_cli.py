import asyncio
import json
import runpy
import socket
import sqlite3
from pathlib import Path

import pytest

from endocam.cli import main
from endocam.cli.study import server_config, trusted_proxies
from endocam.study.db import StudyDB
from endocam.study.manifest import parse_manifest
from endocam.study.responses import ResponseRow, rows_to_csv
from study_helpers import make_study, manifest_dict

pytestmark = pytest.mark.no_kernels  # run while the kernels compile (tests/conftest.py)

MANIFEST = parse_manifest(json.dumps(manifest_dict()))


def _rows(n: int) -> list[ResponseRow]:
    return [
        ResponseRow(
            participant_id=f"p{k}",
            video_id=v.id,
            reported_touches=v.true_touches + (k % 3) * (1 + (v.condition == "centering")),
            attention_passed=k != 0,
        )
        for k in range(n)
        for v in MANIFEST.videos
    ]


@pytest.fixture
def files(tmp_path: Path) -> tuple[Path, Path]:
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps(manifest_dict()), encoding="utf-8")
    responses = tmp_path / "responses.csv"
    responses.write_text(rows_to_csv(_rows(9)), encoding="utf-8")
    return manifest, responses


def test_analyze_from_csv_and_db_agree(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest, responses = files
    out_csv, out_db = tmp_path / "a", tmp_path / "b"
    args = ["study", "analyze", "--manifest", str(manifest), "--outliers", "none"]
    assert main([*args, "--responses", str(responses), "--out", str(out_csv)]) == 0
    printed = capsys.readouterr().out  # the assessor statistics, one line each
    assert "Kendall's W" in printed and "ICC(2,1)" in printed and "Pitman–Morgan" in printed
    db = StudyDB(tmp_path / "s.db")
    for k in range(9):
        participant, _ = db.create_participant(f"p{k}", 6)
        for r in _rows(9):
            if r.participant_id == participant.participant_id:
                db.record_answer(participant, r.video_id, r.reported_touches)
        db.record_attention(participant, 4 if k else 0, k != 0)
    beside = sorted(p.name for p in tmp_path.iterdir())
    assert "s.db-wal" not in beside  # a WAL database, fully checkpointed (no server running)
    assert main([*args, "--db", str(tmp_path / "s.db"), "--out", str(out_db)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*beside, "b"])  # no -wal/-shm
    a = json.loads((out_csv / "analysis.json").read_text())
    b = json.loads((out_db / "analysis.json").read_text())
    assert a == b
    assert a["excluded"] == [{"participant_id": "p0", "reason": "failed the attention question"}]
    assert a["conditions"]["fixed"]["n"] == 8


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--responses", "missing.csv"], "cannot read responses"),
        (["--responses", "RESP", "--tukey-k", "0"], "--tukey-k"),
        (["--db", "missing.db"], "--db"),
    ],
)
def test_analyze_user_errors_are_one_line_exit_2(
    files: tuple[Path, Path],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    extra: list[str],
    needle: str,
) -> None:
    manifest, responses = files
    extra = [str(responses) if e == "RESP" else e for e in extra]
    code = main(
        ["study", "analyze", "--manifest", str(manifest), "--out", str(tmp_path / "o"), *extra]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert needle in err and err.count("\n") == 1


def test_bad_manifest_and_serve_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "manifest.json"
    bad.write_text("{}", encoding="utf-8")
    code = main(["study", "analyze", "--manifest", str(bad), "--responses", "x", "--out", "o"])
    assert code == 2 and "manifest" in capsys.readouterr().err
    assert main(["study", "serve", "--study", str(tmp_path / "none"), "--db", "x.db"]) == 2
    assert "no manifest.json" in capsys.readouterr().err
    # a study folder whose videos are missing is refused before the server starts
    bad.write_text(json.dumps(manifest_dict()), encoding="utf-8")
    assert main(["study", "serve", "--study", str(tmp_path), "--db", str(tmp_path / "s.db")]) == 2
    assert "video files missing" in capsys.readouterr().err


def _analyze(manifest: Path, out: Path, *source: str) -> int:
    return main(["study", "analyze", "--manifest", str(manifest), "--out", str(out), *source])


def test_analyze_never_writes_into_an_empty_db_and_refuses_empty_sources(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest, responses = files
    empty = tmp_path / "empty.db"
    empty.touch()
    assert _analyze(manifest, tmp_path / "o1", "--db", str(empty)) == 2
    err = capsys.readouterr().err
    assert "not a study database" in err and err.count("\n") == 1
    assert empty.read_bytes() == b""  # the schema was not written into the input
    StudyDB(tmp_path / "fresh.db")  # a study database without answers
    assert _analyze(manifest, tmp_path / "o2", "--db", str(tmp_path / "fresh.db")) == 2
    err = capsys.readouterr().err
    assert "no answers" in err and err.count("\n") == 1
    header_only = tmp_path / "header.csv"
    header_only.write_text(responses.read_text().splitlines()[0] + "\n", encoding="utf-8")
    assert _analyze(manifest, tmp_path / "o3", "--responses", str(header_only)) == 2
    err = capsys.readouterr().err
    assert "no data rows" in err and err.count("\n") == 1
    assert not (tmp_path / "o3").exists()


def test_analyze_reads_a_spreadsheet_csv_and_names_a_non_utf8_file(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    manifest, responses = files
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + responses.read_bytes().replace(b"\n", b"\r\n"))
    assert _analyze(manifest, tmp_path / "o1", "--responses", str(bom)) == 0
    capsys.readouterr()
    latin = tmp_path / "latin1.csv"
    latin.write_bytes(responses.read_bytes().replace(b"p1,", "pé,".encode("latin-1")))
    assert _analyze(manifest, tmp_path / "o2", "--responses", str(latin)) == 2
    err = capsys.readouterr().err
    assert str(latin) in err and "UTF-8" in err and err.count("\n") == 1


@pytest.mark.parametrize("k", ["nan", "inf", "-1"])
def test_tukey_k_must_be_finite_and_positive(
    files: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str], k: str
) -> None:
    manifest, responses = files
    code = _analyze(manifest, tmp_path / "o", "--responses", str(responses), "--tukey-k", k)
    err = capsys.readouterr().err
    assert code == 2 and "--tukey-k" in err and err.count("\n") == 1 and "http" not in err


def test_serve_on_a_busy_port_exits_2_and_creates_no_database(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    study = make_study(tmp_path)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        db = tmp_path / "s.db"
        args = ["study", "serve", "--study", str(study), "--db", str(db), "--port", str(port)]
        assert main(args) == 2
    err = capsys.readouterr().err
    assert f"127.0.0.1:{port}" in err and err.count("\n") == 1
    assert not db.exists()


def test_analyze_reads_answers_still_in_the_wal_of_a_running_server(tmp_path: Path) -> None:
    path = tmp_path / "live.db"
    db = StudyDB(path)
    with sqlite3.connect(path) as server:  # a server's connection: keeps the WAL un-checkpointed
        server.execute("PRAGMA wal_autocheckpoint = 0")
        server.execute("SELECT COUNT(*) FROM participants").fetchone()
        participant, _ = db.create_participant("live", 6)
        db.record_answer(participant, "v01", 3)
        files = sorted(p.name for p in tmp_path.iterdir())
        assert files == ["live.db", "live.db-shm", "live.db-wal"]
        rows = StudyDB(path, read_only=True).export_rows()
        assert [(r.participant_id, r.reported_touches) for r in rows] == [("live", 3)]
        assert sorted(p.name for p in tmp_path.iterdir()) == files
    server.close()


def _client_seen_by_the_app(proxies: list[str]) -> str:
    """The client address the app sees for a request from 127.0.0.1 with X-Forwarded-For."""
    seen = []

    async def app(scope: dict, receive: object, send: object) -> None:
        seen.append(scope["client"][0])

    config = server_config(app, proxies)
    config.load()
    scope = {
        "type": "http",
        "client": ("127.0.0.1", 50000),
        "headers": [(b"x-forwarded-for", b"203.0.113.7")],
    }
    asyncio.run(config.loaded_app(scope, None, None))
    return seen[0]


def test_serve_trusts_no_proxy_unless_told(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _client_seen_by_the_app(trusted_proxies(None)) == "127.0.0.1"  # the default
    assert _client_seen_by_the_app(trusted_proxies("127.0.0.1, 10.0.0.0/8")) == "203.0.113.7"
    study = make_study(tmp_path, with_videos=False)
    args = ["study", "serve", "--study", str(study), "--db", str(tmp_path / "s.db")]
    assert main([*args, "--trusted-proxy", "*"]) == 2
    err = capsys.readouterr().err
    assert "--trusted-proxy" in err and err.count("\n") == 1
    assert not (tmp_path / "s.db").exists()


def test_python_m_endocam_is_the_endocam_command(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr("sys.argv", ["endocam", "study", "analyze", "--outliers", "nonsense"])
    with pytest.raises(SystemExit) as exit_info:  # as `python -m endocam ...` runs it
        runpy.run_module("endocam", run_name="__main__", alter_sys=True)
    assert exit_info.value.code == 2  # argparse's usage error, through endocam's parser
    assert "endocam study analyze: error: argument --outliers" in capsys.readouterr().err
