"""The models and the migrations describe one schema: Alembic's autogenerate finds nothing to do
after migrating a fresh database to the newest revision (real Postgres)."""

from __future__ import annotations

from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext
from redline.server.db import get_engine, migrate
from redline.server.models import Base

from tests.support.servers import Services, fresh_database


def test_autogenerate_finds_the_models_and_the_migrated_schema_equal(services: Services):
    database_url, _ = fresh_database(services.database_url)
    migrate(database_url)
    with get_engine(database_url).connect() as connection:
        differences = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    assert differences == []


def test_the_order_key_migration_reorders_what_the_old_keys_misordered(services: Services):
    """Migration 0016 rewrites stored order keys: Arabic-Indic three was ordered after five.
    (Rows are written with the schema as it was at 0015, not with today's models.)"""
    import sqlalchemy as sa
    from alembic import command
    from redline.server.db import alembic_config

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0015")
    order = sa.text("SELECT title FROM revision ORDER BY order_key")
    with get_engine(database_url).begin() as connection:
        component = connection.execute(
            sa.text(
                "INSERT INTO component (name, repo, branch, suite, executions, created, repo_key,"
                " host_labels, description, commit_status)"
                " VALUES ('c', '', 'main', '', 1, now(), '', '[]', '', '{}') RETURNING id"
            )
        ).scalar_one()
        for title, sort_key, old in (("three", "\u0663", "01\u0663"), ("five", "5", "015")):
            connection.execute(
                sa.text(
                    "INSERT INTO revision (component_id, title, sort_key, order_key, commit,"
                    " repo, branch, message, created)"
                    " VALUES (:component, :title, :sort_key, :old, 'main', '', '', '', now())"
                ),
                {"component": component, "title": title, "sort_key": sort_key, "old": old},
            )
        assert list(connection.scalars(order)) == ["five", "three"]  # the old, wrong order
    migrate(database_url)
    with get_engine(database_url).connect() as connection:
        assert list(connection.scalars(order)) == ["three", "five"]


def test_the_triage_migration_keeps_people_triaging_and_takes_it_from_pipelines_tokens(
    services: Services,
):
    """Migration 0022: ``ci`` no longer triages. Users with ``ci`` (people at the pages) and
    their live sessions get ``triage``; API tokens and pasted tokens' sessions do not."""
    import sqlalchemy as sa
    from alembic import command
    from redline.server.db import alembic_config

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0021")
    with get_engine(database_url).begin() as connection:
        people = (("ada", '["ci"]'), ("rita", '["read"]'), ("root", '["admin"]'))
        # a user whose name is what a pasted token's session is called: that session is the
        # token's, and keeps what it had
        for name, scopes in (*people, ("token gitlab", '["ci"]')):
            connection.execute(
                sa.text(
                    "INSERT INTO web_user (name, password_hash, scopes, created, disabled)"
                    " VALUES (:name, 'scrypt$x', CAST(:scopes AS json), now(), false)"
                ),
                {"name": name, "scopes": scopes},
            )
        for secret, who in (("a" * 64, "ada"), ("b" * 64, "token gitlab")):
            connection.execute(
                sa.text(
                    "INSERT INTO web_session (secret_hash, who, scopes, csrf, created, expires)"
                    " VALUES (:secret, :who, '[\"ci\"]', 'c', now(), now() + interval '1 day')"
                ),
                {"secret": secret, "who": who},
            )
        connection.execute(
            sa.text(
                "INSERT INTO api_token (name, token_hash, scopes, created, revoked)"
                " VALUES ('gitlab', :hash, '[\"ci\"]', now(), false)"
            ),
            {"hash": "d" * 64},
        )
    command.upgrade(alembic_config(database_url), "0022")  # 0023 ends every session

    def scopes(query: str) -> dict[str, list[str]]:
        with get_engine(database_url).connect() as connection:
            return {name: list(value) for name, value in connection.execute(sa.text(query))}

    assert scopes("SELECT name, scopes FROM web_user") == {
        "ada": ["ci", "triage"],
        "rita": ["read"],
        "root": ["admin"],
        "token gitlab": ["ci", "triage"],
    }
    assert scopes("SELECT who, scopes FROM web_session") == {
        "ada": ["ci", "triage"],
        "token gitlab": ["ci"],
    }
    assert scopes("SELECT name, scopes FROM api_token") == {"gitlab": ["ci"]}
    migrate(database_url)  # sessions with no owner to check end: their people sign in again
    assert scopes("SELECT who, scopes FROM web_session") == {}
    # back to 0021, where ci triaged: people keep triaging, a token made since loses triage
    with get_engine(database_url).begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO api_token (name, token_hash, scopes, created, revoked)"
                " VALUES ('on-call', :hash, '[\"triage\"]', now(), false)"
            ),
            {"hash": "e" * 64},
        )
        connection.execute(
            sa.text("UPDATE web_user SET scopes = '[\"triage\"]' WHERE name = 'rita'")
        )
    command.downgrade(alembic_config(database_url), "0021")
    assert scopes("SELECT name, scopes FROM web_user")["rita"] == ["ci"]
    assert scopes("SELECT name, scopes FROM web_user")["ada"] == ["ci"]
    assert scopes("SELECT name, scopes FROM api_token") == {"gitlab": ["ci"], "on-call": ["read"]}


def test_the_credentials_migration_strips_passwords_and_tokens_from_stored_repositories(
    services: Services,
):
    """Migration 0024: a URL stored with a password or token (refused since) loses it, in the
    component and in its revisions' copies; an ssh URL keeps its user."""
    import sqlalchemy as sa
    from alembic import command
    from redline.server.db import alembic_config

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0023")
    stored = {
        "https://ci-bot:SECRET@github.com/org/a.git": "https://github.com/org/a.git",
        "https://SECRET@github.com/org/b.git": "https://github.com/org/b.git",
        "ssh://git:SECRET@host:22/c.git": "ssh://git@host:22/c.git",
        "https://ci:SEC@RET@github.com/org/f.git": "https://github.com/org/f.git",
        "ssh://git:SEC@RET@host/g.git": "ssh://git@host/g.git",
        "ssh://git@host/d.git": "ssh://git@host/d.git",
        "git@github.com:org/e.git": "git@github.com:org/e.git",
    }
    with get_engine(database_url).begin() as connection:
        for number, repo in enumerate(stored, start=1):
            ident = connection.execute(
                sa.text(
                    "INSERT INTO component (name, repo, repo_key, branch, suite, executions,"
                    " host_labels, description, commit_status, created) VALUES (:name, :repo, '',"
                    " 'main', '', 1, '[]', '', '{}', now()) RETURNING id"
                ),
                {"name": f"c{number}", "repo": repo},
            ).scalar_one()
            connection.execute(
                sa.text(
                    "INSERT INTO revision (component_id, title, sort_key, order_key, commit,"
                    " branch, repo, created) VALUES (:ident, 'r1', '1', '1', 'abc1234', 'main',"
                    " :repo, now())"
                ),
                {"ident": ident, "repo": repo},
            )
    migrate(database_url)
    with get_engine(database_url).connect() as connection:
        for table in ("component", "revision"):
            kept = connection.execute(sa.text(f"SELECT repo FROM {table} ORDER BY id")).scalars()
            assert list(kept) == list(stored.values()), table


def test_the_token_labels_migration_gives_each_agent_token_its_hosts_labels(services: Services):
    """Migration 0031: a host registers with the labels its token was given. A token issued
    before gets the labels its hosts registered with so far (a pool's, those of every host its
    prefix names), so that no running agent loses its jobs; other tokens get none."""
    import sqlalchemy as sa
    from alembic import command
    from redline.server.db import alembic_config

    database_url, _ = fresh_database(services.database_url)
    command.upgrade(alembic_config(database_url), "0030")
    with get_engine(database_url).begin() as connection:
        for name, labels in (
            ("perf-1", '["x86", "quiet"]'),
            ("compose-a", '["gpu"]'),
            ("compose-b", '["quiet", "gpu"]'),
            ("compose", '["root"]'),  # the prefix alone is not of the pool
        ):
            connection.execute(
                sa.text(
                    "INSERT INTO host (name, fingerprint, labels, last_seen)"
                    " VALUES (:name, '{}', CAST(:labels AS json), now())"
                ),
                {"name": name, "labels": labels},
            )
        for number, (name, scopes, host) in enumerate(
            (
                ("perf-1", '["agent"]', "perf-1"),
                ("pool", '["agent"]', "compose-*"),
                ("unseen", '["agent"]', "perf-9"),
                ("ci", '["ci"]', None),
            )
        ):
            connection.execute(
                sa.text(
                    "INSERT INTO api_token (name, token_hash, scopes, created, revoked, host)"
                    " VALUES (:name, :hash, CAST(:scopes AS json), now(), false, :host)"
                ),
                {"name": name, "hash": str(number) * 64, "scopes": scopes, "host": host},
            )
    migrate(database_url)
    with get_engine(database_url).connect() as connection:
        labels = dict(connection.execute(sa.text("SELECT name, labels FROM api_token")).all())
    assert labels == {
        "perf-1": ["quiet", "x86"],
        "pool": ["gpu", "quiet"],
        "unseen": [],
        "ci": [],
    }
