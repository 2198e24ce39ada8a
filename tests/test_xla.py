"""agentax._xla says when the XLA CPU hang's cure cannot work: synthetic registries, no real client.

The cure (``create_cpu_client_on_one_cpu``) patches jax's private backend registry, and
``let_xla_use_every_cpu`` only works before jax makes its CPU client; both used to fail silently.
Each test swaps in a fake ``jax._src.xla_bridge`` state with monkeypatch, so the process's real
client and factory stay as they are.
"""

from __future__ import annotations

import warnings

import pytest
from jax._src import xla_bridge

from agentax import _xla


@pytest.fixture
def pinning_wanted(monkeypatch):
    monkeypatch.setattr(_xla, "pin_wanted", lambda: True)


@pytest.mark.parametrize(
    "registry",
    [
        {"_backend_factories": {}},  # no CPU factory registered under that name
        {"_backend_factories": {"cpu": object()}},  # a registration without a .factory
        {"_backends": None},  # the created-backends dict renamed or retyped
    ],
    ids=["no-cpu-factory", "no-factory-attribute", "no-backends-dict"],
)
def test_the_cure_warns_once_when_jaxs_private_registry_is_not_there(pinning_wanted, monkeypatch, registry):
    for name, value in registry.items():
        monkeypatch.setattr(xla_bridge, name, value, raising=False)
    with pytest.warns(RuntimeWarning) as caught:
        assert _xla.create_cpu_client_on_one_cpu() is False
    assert len(caught) == 1
    message = str(caught[0].message)
    assert "_backend_factories" in message  # what is missing
    assert "hang" in message and "may return" in message  # the consequence
    assert "AGENTAX_PIN_CPU=0" in message  # how to silence it


def test_the_cure_says_nothing_where_pinning_is_off(monkeypatch):
    monkeypatch.setattr(_xla, "pin_wanted", lambda: False)
    monkeypatch.setattr(xla_bridge, "_backend_factories", {})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _xla.create_cpu_client_on_one_cpu() is False


def test_the_cure_says_nothing_where_the_client_exists_already(pinning_wanted, monkeypatch):
    """Too late, but the registry is there: no warning (the runners' call then decides)."""
    registration = type("Registration", (), {"factory": staticmethod(lambda: None)})()
    monkeypatch.setattr(xla_bridge, "_backend_factories", {"cpu": registration})
    monkeypatch.setattr(xla_bridge, "_backends", {"cpu": object()})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _xla.create_cpu_client_on_one_cpu() is False
    assert not getattr(registration.factory, "agentax_one_cpu", False)  # left alone


def test_the_cure_wraps_the_factory_and_marks_a_client_made_on_one_cpu(pinning_wanted, monkeypatch):
    client = object()
    registration = type("Registration", (), {"factory": staticmethod(lambda: client)})()
    monkeypatch.setattr(xla_bridge, "_backend_factories", {"cpu": registration})
    monkeypatch.setattr(xla_bridge, "_backends", {})
    monkeypatch.setattr(_xla, "_client_made_on_one_cpu", False)
    monkeypatch.setattr(_xla, "_one_cpu_client", True)
    monkeypatch.setattr(_xla.os, "sched_getaffinity", lambda pid: {0, 1})
    pinned = []
    monkeypatch.setattr(_xla.os, "sched_setaffinity", lambda pid, cpus: pinned.append(set(cpus)))
    monkeypatch.setattr(_xla, "thread_ids", lambda: [])
    assert _xla.create_cpu_client_on_one_cpu() is True
    assert registration.factory.agentax_one_cpu
    assert registration.factory() is client
    assert len(pinned[0]) == 1 and pinned[-1] == {0, 1}  # one CPU while it made the client, then all
    assert _xla._client_made_on_one_cpu


def test_every_cpu_asked_too_late_warns_when_the_client_was_made_on_one_cpu(monkeypatch):
    monkeypatch.setattr(xla_bridge, "_backends", {"cpu": object()})
    monkeypatch.setattr(_xla, "_client_made_on_one_cpu", True)
    monkeypatch.setattr(_xla, "_one_cpu_client", True)
    with pytest.warns(RuntimeWarning, match="no faster than sequential") as caught:
        assert _xla.let_xla_use_every_cpu() is False
    assert len(caught) == 1 and "AGENTAX_PIN_CPU=0" in str(caught[0].message)
    assert caught[0].filename == __file__  # points at the caller (a runner), not at _xla.py
    assert _xla._one_cpu_client  # nothing changed


def test_every_cpu_asked_too_late_says_nothing_where_it_does_not_matter(monkeypatch):
    """A client made for every CPU (pinning off, one allowed CPU, or asked for in time): no cost."""
    monkeypatch.setattr(xla_bridge, "_backends", {"cpu": object()})
    monkeypatch.setattr(_xla, "_client_made_on_one_cpu", False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _xla.let_xla_use_every_cpu() is False


def test_every_cpu_asked_in_time_takes_effect_silently(monkeypatch):
    monkeypatch.setattr(xla_bridge, "_backends", {})
    monkeypatch.setattr(_xla, "_one_cpu_client", True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _xla.let_xla_use_every_cpu() is True
    assert _xla._one_cpu_client is False  # monkeypatch puts True back
