"""The Resource Registrar (docs/architecture.md)."""
from temoto_core.rr.registrar import ResourceRegistrar
from temoto_core.rr.registry import RegistrySnapshot
from temoto_core.rr.status import Status, StatusEvent

__all__ = ['ResourceRegistrar', 'RegistrySnapshot', 'Status', 'StatusEvent']
