"""Where alerts may not be sent (`redline.server.core.targets`): link-local and metadata
addresses, however written; loopback and private networks stay allowed."""

from __future__ import annotations

import pytest
from pydantic import ValidationError
from redline.server.core.targets import refused_address, refused_host
from redline.server.schemas.alerts import CommitStatusTarget, SubscriptionCreate


@pytest.mark.parametrize(
    "address",
    [
        "169.254.169.254",
        "169.254.0.1",
        "fe80::1",
        "fe80::1%eth0",
        "::ffff:169.254.169.254",
        "fd00:ec2::254",
        "100.100.100.200",
        "224.0.0.1",
        "0.0.0.0",
        "::",
    ],
)
def test_link_local_metadata_multicast_and_unspecified_addresses_are_refused(address) -> None:
    said = refused_address(address)
    assert said is not None and said.startswith(f"{address} is a ")


@pytest.mark.parametrize(
    "address", ["127.0.0.1", "::1", "10.1.2.3", "192.168.0.10", "172.16.5.4", "8.8.8.8", "chat"]
)
def test_loopback_private_and_public_addresses_and_names_are_allowed(address) -> None:
    assert refused_address(address) is None


def test_a_name_is_judged_by_what_it_resolves_to() -> None:
    assert refused_host("localhost") is None
    assert refused_host("no-such-host.invalid") is None  # the connection says it
    assert refused_host("169.254.169.254") == (
        "169.254.169.254 is a link-local or cloud metadata address"
    )


def test_subscriptions_and_commit_status_targets_refuse_such_a_url_naming_it() -> None:
    with pytest.raises(ValidationError, match="must not point at 169.254.169.254 is a link-local"):
        SubscriptionCreate(kind="webhook", url="http://169.254.169.254/latest/meta-data/")
    with pytest.raises(ValidationError, match="fe80::1 is a link-local"):
        CommitStatusTarget(
            provider="github", repository="a/b", api_url="http://[fe80::1]/api", token="t"
        )
    assert SubscriptionCreate(kind="webhook", url="http://127.0.0.1:8080/hook").url
