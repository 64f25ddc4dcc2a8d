"""Where alerts may not be sent (`redline.server.core.targets`): link-local and metadata
addresses, however written; loopback and private networks stay allowed; no URL that cannot be
sent to."""

from __future__ import annotations

import httpx
import pytest
from pydantic import ValidationError
from redline.server.core.targets import refused_address, refused_host
from redline.server.schemas.alerts import CommitStatusTarget, SubscriptionCreate
from redline.worker import sending


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
    assert said is not None and said.startswith(address) and " is a " in said


@pytest.mark.parametrize(
    "address",
    [
        "2852039166",  # decimal
        "0251.0376.0251.0376",  # octal
        "0xa9fea9fe",  # hex
        "169.254.43518",  # short
        "::169.254.169.254",  # IPv4-compatible
        "64:ff9b::a9fe:a9fe",  # NAT64
        "2002:a9fe:a9fe::",  # 6to4
        "169\u3002254\u3002169\u3002254",  # ideographic full stops, which IDNA reads as dots
        "169\uff0e254\uff0e169\uff0e254",  # fullwidth full stops
        "\u2460\u2465\u2468.\u2461\u2464\u2463.\u2460\u2465\u2468.\u2461\u2464\u2463",  # circled
        "\uff11\uff16\uff19.254.169.254",  # fullwidth digits
        "169.254.169.254.",  # the root's trailing dot, which some clients drop (a trial's passed)
        "0xa9fea9fe.",
        "169\u3002254\u3002169\u3002254\u3002",
    ],
)
def test_the_metadata_address_in_any_form_a_resolver_reads_is_refused(address) -> None:
    assert refused_address(address) == (
        f"{address} (169.254.169.254) is a link-local or cloud metadata address"
    )


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
    # the resolver's own reading, as a delivery checks a name (no network needed for it)
    assert refused_host("2852039166") is not None


def test_subscriptions_and_commit_status_targets_refuse_such_a_url_naming_it() -> None:
    with pytest.raises(
        ValidationError, match="must not point at this host: 169.254.169.254 is a link-local"
    ):
        SubscriptionCreate(kind="webhook", url="http://169.254.169.254/latest/meta-data/")
    with pytest.raises(ValidationError, match="fe80::1 is a link-local"):
        CommitStatusTarget(
            provider="github", repository="a/b", api_url="http://[fe80::1]/api", token="t"
        )
    with pytest.raises(ValidationError, match=r"2852039166 \(169.254.169.254\) is a link-local"):
        SubscriptionCreate(kind="webhook", url="http://2852039166/latest/meta-data/")
    assert SubscriptionCreate(kind="webhook", url="http://127.0.0.1:8080/hook").url


@pytest.mark.parametrize(
    ("url", "said"),
    [
        ("http://a\x00b/", r"'\\x00' at position 8"),
        ("http://1\x00/", r"'\\x00' at position 8"),
        ("http://exa\tmple.com/hook", r"'\\t' at position 10"),
        ("http://hooks.example.com/a\nb", r"'\\n' at position 26"),
        ("http://ex ample.com/", "' ' at position 9"),
    ],
)
def test_a_url_with_a_control_character_or_a_space_is_refused_naming_it(url, said) -> None:
    # accepted before, these failed at each delivery attempt (httpx refuses to send them), and
    # a null character raised out of the address check instead of a clear refusal
    with pytest.raises(ValidationError, match="must not contain " + said):
        SubscriptionCreate(kind="webhook", url=url)


def test_an_address_check_of_a_name_holding_a_null_character_says_it_is_no_address() -> None:
    assert refused_address("1.2.3.4\x00") is None
    assert refused_host("a\x00b") is None  # the connection refuses it, and says so


def test_a_stored_url_that_cannot_be_sent_to_fails_its_delivery_for_good_saying_why() -> None:
    # a subscription stored before such URLs were refused: retrying it for days mends nothing
    with httpx.Client() as client, pytest.raises(sending.SendError) as failed:
        sending._post(client, "http://hooks.example.com/a\tb", b"{}", {}, timeout=1.0)
    assert failed.value.permanent
    assert str(failed.value).startswith("invalid URL: Invalid non-printable ASCII character")


@pytest.mark.parametrize("url", ["https://user:s3cret@hooks.example/x", "https://token@h.example/"])
def test_a_target_url_carrying_a_user_or_password_is_refused(url) -> None:
    # a probe's showed in full in the settings page and in the API's answers to admins
    with pytest.raises(ValidationError, match="must not carry a user or password"):
        SubscriptionCreate(kind="webhook", url=url)
    with pytest.raises(ValidationError, match="commit status a 'token' instead"):
        CommitStatusTarget(provider="github", repository="a/b", api_url=url, token="t")
