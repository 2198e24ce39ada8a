"""Joining or starting a Ray cluster (:func:`ray_session`): the one module that touches Ray's private
``ray._raylet``, to send this machine's token to ``HOST:PORT`` and refuse a wrong one at once.
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from agentax.errors import UsageError


@contextmanager
def ray_session(address: str | None) -> Iterator[Any]:
    """Connected to Ray for the length of the block: the cluster at ``address``, else a local Ray
    started here and shut down after (its processes end with it). A connection made before is kept."""
    try:
        import ray
    except ImportError:
        raise UsageError("--runner ray needs Ray: pip install 'agentax[ray]'") from None
    if ray.is_initialized():
        yield ray
        return
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False, "include_dashboard": False}
    with token_auth_to_join(address):
        try:
            if address:
                refuse_if_token_refused(address)
                ray.init(address=address, **quiet)
            else:
                # "local": a Ray of this run's own even where one is running already (a user's
                # `ray start --head`), which plain ray.init() would join and then refuse num_cpus for
                ray.init(address="local", num_cpus=os.cpu_count(), **quiet)
        except ConnectionError as error:
            raise UsageError(join_failure(address, error)) from None
        try:
            yield ray
        finally:
            ray.shutdown()


# ---------------------------------------------------------------- Ray's token authentication

AUTH_MODE = "RAY_AUTH_MODE"
"""Ray's switch (2.52+): ``token`` sends and checks the cluster's token; unset, Ray 2.60 turns it on
for a new local Ray, ``ray start --head`` and ``ray.init("auto")`` with a token at hand, never for
``ray.init("HOST:PORT")`` nor ``ray start --address``"""


def has_token() -> bool:
    """Whether Ray finds a token here (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``, ``~/.ray/auth_token``)."""
    try:
        from ray._raylet import AuthenticationTokenLoader
    except ImportError:  # a Ray without token authentication
        return False
    loader = AuthenticationTokenLoader.instance()
    try:
        return loader.has_token(ignore_auth_mode=True)
    except Exception:  # an unreadable RAY_AUTH_TOKEN_PATH: ray.init says so
        return False


@contextmanager
def token_auth_to_join(address: str | None) -> Iterator[None]:
    """Joining ``HOST:PORT`` sends this machine's token, as ``ray.init("auto")`` does: with
    ``RAY_AUTH_MODE`` unset and a token at hand, token authentication is on for the block."""
    if not is_host_port(address) or AUTH_MODE in os.environ or not has_token():
        yield
        return
    from ray._raylet import Config

    os.environ[AUTH_MODE] = "token"
    Config.initialize("")  # Ray reads the mode from its config, refreshed from the environment
    try:
        yield
    finally:
        del os.environ[AUTH_MODE]
        Config.initialize("")


def is_host_port(address: str | None) -> bool:
    return bool(address) and address != "auto" and "://" not in address and ":" in address


def refuse_if_token_refused(address: str) -> None:
    """A ``UsageError`` at once when the cluster at ``HOST:PORT`` refuses this machine's token (or its
    lack of one), where ``ray.init`` would retry for 20 s and say "Failed to connect"."""
    if not is_host_port(address):
        return
    host, _, port = address.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5).close()
        from ray._raylet import GcsClient
        from ray.exceptions import AuthenticationError
    except (OSError, ValueError, ImportError):
        return
    try:
        GcsClient(address=address)  # asks the cluster's GCS for its id, the token checked
    except AuthenticationError:
        raise UsageError(token_refused(address)) from None
    except Exception:
        return


def token_refused(address: str) -> str:
    """What to do when the cluster at ``address`` refuses this machine's token, in one line."""
    head_token = (
        "the head machine's token (copy its ~/.ray/auth_token here, or set RAY_AUTH_TOKEN to what "
        "`ray get-auth-token` prints there)"
    )
    mode = os.environ.get(AUTH_MODE, "")
    if mode and mode.lower() != "token":
        why = f"wants an authentication token and {AUTH_MODE}={mode} here sends none"
        return f"the Ray cluster at {address} {why}: set {AUTH_MODE}=token and use {head_token}"
    if not has_token():
        why = "wants an authentication token and this machine has none"
        return f"the Ray cluster at {address} {why}: use {head_token}"
    return f"the Ray cluster at {address} refused this machine's authentication token: use {head_token}"


def join_failure(address: str | None, error: ConnectionError) -> str:
    """The one line for a ``ray.init`` that could not join ``address``."""
    causes, cause = [], error
    while cause is not None:
        causes.append(str(cause))
        cause = cause.__cause__ or cause.__context__
    if any("InvalidAuthToken" in text or "AuthenticationError" in text for text in causes):
        return token_refused(str(address))
    return f"cannot join the Ray cluster at {address!r}: {error}"
