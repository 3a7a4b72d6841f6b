"""Fixtures several test modules share.

``postgres_url``: a real PostgreSQL server for the store's tests. When
``RAILSTOP_TEST_POSTGRES_URL`` names a database the tests may empty, that one;
otherwise a throwaway cluster the fixture makes with the machine's own
PostgreSQL binaries (``initdb``, ``pg_ctl``; Debian puts them in
``/usr/lib/postgresql/VERSION/bin``) in a temporary folder, listening on a free
loopback port, stopped and removed at the end of the session. As root it runs
them as the ``postgres`` user (PostgreSQL refuses to run as root). Without
the binaries the tests that need it are skipped with the reason.

``empty_postgres``: that server's database with none of the store's tables,
before the test and after it.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest


def _bindir() -> Path | None:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(Path(p).parts[-3]))
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return None if initdb is None else Path(initdb).parent


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    given = os.environ.get("RAILSTOP_TEST_POSTGRES_URL")
    if given:
        yield given
        return
    bindir = _bindir()
    if bindir is None:
        pytest.skip("no PostgreSQL server binaries (initdb, pg_ctl) on this machine")
    as_user: list[str] = []
    owner: tuple[int, int] | None = None
    if os.geteuid() == 0:
        import pwd

        try:
            pw = pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user to run PostgreSQL as")
        as_user = ["runuser", "-u", "postgres", "--"]
        owner = (pw.pw_uid, pw.pw_gid)
    top = Path(tempfile.mkdtemp(prefix="railstop-pg-"))
    top.chmod(0o755)
    data, sockets, logs = top / "data", top / "sock", top / "log"
    log = logs / "server.log"
    for d in (data, sockets, logs):
        d.mkdir()
        if owner is not None:
            os.chown(d, *owner)
    port = _free_port()

    def run(*argv: str) -> None:
        subprocess.run([*as_user, *argv], check=True, capture_output=True, text=True, timeout=120)

    try:
        run(
            str(bindir / "initdb"),
            "-D",
            str(data),
            "-A",
            "trust",
            "-U",
            "railstop",
            "--no-sync",
            "-E",
            "UTF8",
        )
        run(
            str(bindir / "pg_ctl"),
            "-D",
            str(data),
            "-l",
            str(log),
            "-w",
            "-t",
            "60",
            "-o",
            f"-p {port} -k {sockets} -c listen_addresses=127.0.0.1 -c fsync=off",
            "start",
        )
    except subprocess.CalledProcessError as exc:
        text = log.read_text(errors="replace") if log.exists() else ""
        shutil.rmtree(top, ignore_errors=True)
        pytest.fail(f"could not start PostgreSQL: {exc.stderr or exc.stdout} {text[-500:]}")
    try:
        yield f"postgresql://railstop@127.0.0.1:{port}/postgres"
    finally:
        with contextlib.suppress(subprocess.SubprocessError, OSError):
            run(str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop")
        shutil.rmtree(top, ignore_errors=True)


@pytest.fixture
def empty_postgres(postgres_url: str) -> Iterator[str]:
    from sqlalchemy import create_engine, text

    from railstop.store.db import _Base

    engine = create_engine(postgres_url.replace("postgresql://", "postgresql+psycopg://", 1))

    def empty() -> None:
        # Every table the store knows (a test may have made older layouts of them): CASCADE, so
        # that no foreign key of an old layout stands in the way.
        with engine.begin() as con:
            for table in _Base.metadata.tables:
                con.execute(text(f"DROP TABLE IF EXISTS {table} CASCADE"))

    empty()
    try:
        yield postgres_url
    finally:
        empty()
        engine.dispose()
