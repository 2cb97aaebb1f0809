"""Zenoh sessions as dcobserver configures them: keys, endpoints, TLS, user/password, access.

Every session the project opens (the daemon's publisher, ``dcobserver
subscribe``, ``dcobserver router``) is built here from a
:class:`observer.config.ZenohLinkConfig`, so a security option means the same
in each of them.

Keys are ``dcobserver/<drive_id>/<leaf>``, or ``dcobserver/<drive_id>/<motor_id>/<leaf>``
when a drive's motors each have a daemon; leaves are ``estimate``, ``health``
and ``latest`` (a queryable). Access control is granted per drive: the
identities listed for a drive may publish ``dcobserver/<drive_id>/**``, the
listed subscribers may subscribe to and query ``dcobserver/**``, and nothing
else passes (Zenoh drops denied messages silently, it raises no error).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from observer.config import AccessConfig, ZenohLinkConfig

ROOT = "dcobserver"


def zenoh_error(exc: BaseException) -> str:
    """A Zenoh error as one line for users: without the Rust source paths it carries."""
    import re

    text = " ".join(str(exc).split())
    text = re.sub(r"\s*at /\S+\.rs:\d+\.?", "", text)
    return text.strip(" .[]") or type(exc).__name__


#: Messages a drive's observer sends into a session (its estimates and health, its
#: ``latest`` queryable and the replies to queries of it).
_PUBLISHER_INGRESS = ["put", "delete", "declare_queryable", "reply"]
#: What a drive's observer must be told: that subscribers match its keys (without
#: it a client drops its puts before sending) and the queries for ``latest``.
_PUBLISHER_EGRESS = ["declare_subscriber", "query"]
_SUBSCRIBER_INGRESS = ["declare_subscriber", "query"]
_SUBSCRIBER_EGRESS = ["put", "delete", "reply"]


def key(drive_id: str, leaf: str, motor_id: str = "") -> str:
    """The key of one leaf of a drive's (or one of its motors') observer."""
    return "/".join(p for p in (ROOT, drive_id, motor_id, leaf) if p)


def names(drive_id: str, motor_id: str = "") -> dict[str, str]:
    """The names every estimate and health message carries (``motor_id`` only when set)."""
    return {"drive_id": drive_id, **({"motor_id": motor_id} if motor_id else {})}


def parse_key(key_expr: str) -> tuple[str, str, str]:
    """``(drive_id, motor_id, leaf)`` of a key made by :func:`key`; ``motor_id`` may be ""."""
    chunks = str(key_expr).split("/")
    if len(chunks) < 3 or chunks[0] != ROOT:
        return "", "", chunks[-1]
    return chunks[1], "/".join(chunks[2:-1]), chunks[-1]


def session_config(link: ZenohLinkConfig, mode: str) -> dict[str, Any]:
    """The ``zenoh.Config`` of a session in ``mode`` (``peer``, ``client`` or ``router``).

    Reads ``auth.password_file``; raises OSError if it cannot be read.
    """
    config: dict[str, Any] = {
        "mode": mode,
        "listen": {"endpoints": list(link.listen)},
        "connect": {"endpoints": list(link.connect)},
        "scouting": {
            "multicast": {"enabled": link.multicast_scouting},
            "gossip": {"enabled": link.multicast_scouting},
        },
    }
    transport: dict[str, Any] = {}
    tls = link.tls
    if tls.enabled:
        options: dict[str, Any] = {
            "root_ca_certificate": tls.root_ca,
            "enable_mtls": tls.mutual,
            "verify_name_on_connect": tls.verify_name,
        }
        if tls.certificate:
            options["listen_certificate"] = tls.certificate
            options["listen_private_key"] = tls.private_key
            if tls.mutual:
                options["connect_certificate"] = tls.certificate
                options["connect_private_key"] = tls.private_key
        transport["link"] = {"tls": options}
    auth = link.auth
    if auth.user or auth.dictionary_file:
        usrpwd: dict[str, Any] = {}
        if auth.user:
            usrpwd["user"] = auth.user
            usrpwd["password"] = read_password(auth.password_file)
        if auth.dictionary_file:
            usrpwd["dictionary_file"] = auth.dictionary_file
        transport["auth"] = {"usrpwd": usrpwd}
    if transport:
        config["transport"] = transport
    if link.access.enabled:
        config["access_control"] = access_control(link.access)
    return config


def with_endpoints(
    link: ZenohLinkConfig,
    listen: Sequence[str] | None,
    connect: Sequence[str] | None,
    *,
    default_listen: Sequence[str] = (),
    default_connect: Sequence[str] = (),
) -> ZenohLinkConfig:
    """``link`` with the endpoints given on a command line (None: the link's own).

    Where neither gives any endpoint, the defaults apply. Raises ValueError on a
    bad endpoint (or a ``tls/`` endpoint without ``[zenoh.tls]``).
    """
    new_listen = list(listen) if listen is not None else list(link.listen)
    new_connect = list(connect) if connect is not None else list(link.connect)
    if not new_listen and not new_connect:
        new_listen, new_connect = list(default_listen), list(default_connect)
    return dataclasses.replace(link, listen=new_listen, connect=new_connect)


def session_json(link: ZenohLinkConfig, mode: str) -> str:
    """:func:`session_config` as the JSON5 text ``zenoh.Config.from_json5`` reads."""
    return json.dumps(session_config(link, mode))


def read_password(path: str) -> str:
    """The first line of a password file, without its line end."""
    lines = Path(path).read_text().splitlines()
    return lines[0] if lines else ""


def access_control(access: AccessConfig) -> dict[str, Any]:
    """Zenoh's ``access_control`` for these grants; everything else is denied."""
    attribute = "cert_common_names" if access.identify_by == "common_name" else "usernames"
    subjects: dict[str, dict[str, Any]] = {}

    def subject(identity: str) -> str:
        subject_id = f"{access.identify_by}:{identity}"
        subjects.setdefault(subject_id, {"id": subject_id, attribute: [identity]})
        return subject_id

    rules: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []

    def grant(rule_id: str, flow: str, messages: list[str], keyexpr: str, who: list[str]) -> None:
        if not who:
            return
        rules.append(
            {
                "id": rule_id,
                "permission": "allow",
                "flows": [flow],
                "messages": messages,
                "key_exprs": [keyexpr],
            }
        )
        policies.append({"rules": [rule_id], "subjects": [subject(i) for i in who]})

    everything = f"{ROOT}/**"
    all_publishers: list[str] = []
    for drive, identities in sorted(access.publishers.items()):
        grant(f"publish {drive}", "ingress", _PUBLISHER_INGRESS, f"{ROOT}/{drive}/**", identities)
        all_publishers += [i for i in identities if i not in all_publishers]
    grant("publishers see subscribers", "egress", _PUBLISHER_EGRESS, everything, all_publishers)
    grant("subscribe", "ingress", _SUBSCRIBER_INGRESS, everything, access.subscribers)
    grant("deliver", "egress", _SUBSCRIBER_EGRESS, everything, access.subscribers)
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": list(subjects.values()),
        "policies": policies,
    }
