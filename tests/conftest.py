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


@contextlib.contextmanager
def _throwaway_cluster(prefix: str, *, synchronous_commit: bool) -> Iterator[PgCluster]:
    """A PostgreSQL cluster of the machine's binaries in a temporary folder, on a free loopback
    port, started; stopped and removed at the end (the tests are skipped without the binaries)."""
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
    top = Path(tempfile.mkdtemp(prefix=prefix))
    top.chmod(0o755)
    for d in (top / "data", top / "sock", top / "log"):
        d.mkdir()
        if owner is not None:
            os.chown(d, *owner)
    cluster = PgCluster(top, bindir, as_user, _free_port(), synchronous_commit=synchronous_commit)
    try:
        cluster._run(str(bindir / "initdb"), "-D", str(cluster.data), "-A", "trust", "-U", "railstop",
                     "--no-sync", "-E", "UTF8")  # fmt: skip
        cluster.start()
    except subprocess.CalledProcessError as exc:
        text = cluster.log.read_text(errors="replace") if cluster.log.exists() else ""
        shutil.rmtree(top, ignore_errors=True)
        pytest.fail(f"could not start PostgreSQL: {exc.stderr or exc.stdout} {text[-500:]}")
    try:
        yield cluster
    finally:
        with contextlib.suppress(subprocess.SubprocessError, OSError):
            cluster.stop("immediate")
        shutil.rmtree(top, ignore_errors=True)


@pytest.fixture(scope="session")
def postgres_url() -> Iterator[str]:
    given = os.environ.get("RAILSTOP_TEST_POSTGRES_URL")
    if given:
        yield given
        return
    with _throwaway_cluster("railstop-pg-", synchronous_commit=True) as cluster:
        yield cluster.url


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


# ---------------------------------------------------------------------- a loaded machine
# ``busy``: two CPU-bound processes beside the test (``tests/busy.py``), so that a live test shows
# it holds when the cores are taken by other work. ``pytest --busy N`` runs N of them beside every
# test of the session (``pytest --busy 2 tests/e2e/test_live.py``: the live suite on a loaded machine).


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--busy",
        type=int,
        default=0,
        metavar="N",
        help="run N CPU-bound processes beside every test (a loaded machine; tests/busy.py)",
    )


@pytest.fixture
def busy() -> Iterator[object]:
    from busy import busy as spinning

    with spinning(2) as b:
        yield b


@pytest.fixture(autouse=True)
def _busy_beside_every_test(request: pytest.FixtureRequest) -> Iterator[None]:
    n = int(request.config.getoption("--busy"))
    if n <= 0:
        yield
        return
    from busy import busy as spinning

    with spinning(n):
        yield


# ---------------------------------------------------------------------- a PostgreSQL to restart
# ``restartable_postgres``: a throwaway cluster of its own (like ``postgres_url``'s, for the tests of
# one module) that a test may stop and start again (``.stop()``, ``.start()``) to show a client
# surviving a server restart. Its server default is ``synchronous_commit=off``, so that a test can
# show the store asking for durable commits itself.


class PgCluster:
    """A throwaway PostgreSQL cluster: ``url``, ``stop()`` (fast shutdown), ``start()``."""

    def __init__(
        self, top: Path, bindir: Path, as_user: list[str], port: int, *, synchronous_commit: bool = False
    ) -> None:
        self.top, self.bindir, self.as_user, self.port = top, bindir, as_user, port
        self.synchronous_commit = synchronous_commit
        self.data, self.sockets, self.log = top / "data", top / "sock", top / "log" / "server.log"
        self.url = f"postgresql://railstop@127.0.0.1:{port}/postgres"

    def _run(self, *argv: str) -> None:
        subprocess.run([*self.as_user, *argv], check=True, capture_output=True, text=True, timeout=120)

    def start(self) -> None:
        opts = f"-p {self.port} -k {self.sockets} -c listen_addresses=127.0.0.1 -c fsync=off"
        opts += "" if self.synchronous_commit else " -c synchronous_commit=off"
        self._run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-l", str(self.log), "-w", "-t", "60",
                  "-o", opts, "start")  # fmt: skip

    def stop(self, mode: str = "fast") -> None:
        self._run(str(self.bindir / "pg_ctl"), "-D", str(self.data), "-m", mode, "-w", "stop")


@pytest.fixture(scope="module")
def restartable_postgres() -> Iterator[PgCluster]:
    with _throwaway_cluster("railstop-pg-restart-", synchronous_commit=False) as cluster:
        yield cluster


# ---------------------------------------------------------------------- the order of the suite
# The slow modules first: pytest-xdist hands out tests in collection order, so a long test left to
# the end keeps one worker busy while the others idle. The live modules mostly wait on the wall
# clock, so starting them early also overlaps their waiting with the compute-bound tests (``make
# test`` runs e2e/test_live.py, e2e/test_control_room.py, e2e/test_live_attack.py and
# live/test_live_plant.py in a pytest of their own beside the rest; the order matters when the whole
# suite runs in one). Only the order
# changes; every test still runs. The modules are named by their path under ``tests/``.

_SLOW_FIRST = (
    "verify/test_zones_verify.py",
    "e2e/test_live.py",
    "e2e/test_control_room.py",
    "e2e/test_control_room_security.py",
    "e2e/test_live_attack.py",
    "live/test_office_db.py",
    "live/test_office.py",
)
_TESTS = Path(__file__).resolve().parent


def _under_tests(path: Path) -> str:
    """``path`` relative to ``tests/`` (``e2e/test_live.py``), or as it is when it lies elsewhere."""
    try:
        return path.resolve().relative_to(_TESTS).as_posix()
    except ValueError:
        return path.as_posix()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {name: i for i, name in enumerate(_SLOW_FIRST)}
    # Stable: the same order within a rank.
    items.sort(key=lambda item: rank.get(_under_tests(item.path), len(_SLOW_FIRST)))
