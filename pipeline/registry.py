"""Algorithms that register: each declared once (name, parameter model, reach, function), read by everything else.

A plugin keeps one :class:`Registry` per kind of algorithm.  The
configuration's schema takes a mapping ``{name: ..., <parameters>}`` and
validates it by the model of the algorithm it names (:meth:`Registry.field`);
an unknown name is a configuration error that lists the known ones.  A
stage's tile buffer is the algorithm's reach, its commands offer the
registered names and the configuration reference lists them: nothing else
keeps a copy of the list.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from pydantic import BaseModel
from pydantic_core import PydanticCustomError, core_schema


@dataclass(frozen=True)
class Algorithm:
    """One algorithm of a kind.

    *params*: its parameter model (a field ``name`` holding the algorithm's
    name; None: it has no parameters); *reach*: how far it looks from a
    point, in the unit of the extent the stage tiles, given its parameters
    (the buffer a tile needs); *function*: the computation, with the
    signature its kind says; *summary*: one line for the docs and the
    commands' help.
    """

    name: str
    params: type[BaseModel] | None
    reach: Callable[[Any], float]
    function: Callable[..., Any]
    summary: str = ""

    @property
    def module(self) -> str:
        """The module that defines the function: imported where the algorithm runs, so that it registers there too."""
        return self.function.__module__


A = TypeVar("A", bound=Algorithm)


class Registry(Generic[A]):
    """The algorithms of one *kind* (its name in messages: "interpolation method", say), by name."""

    def __init__(self, kind: str):
        self.kind = kind
        self._entries: dict[str, A] = {}

    def register(self, entry: A) -> A:
        """Declare an algorithm; a second one of the same name is a programming error."""
        if entry.name in self._entries:
            raise ValueError(f"a {self.kind} named {entry.name!r} is registered already")
        self._entries[entry.name] = entry
        return entry

    def unregister(self, name: str) -> None:
        """Forget an algorithm (tests that register one of their own)."""
        del self._entries[name]

    def names(self) -> list[str]:
        """The registered names, sorted."""
        return sorted(self._entries)

    def __iter__(self) -> Iterator[A]:
        return (self._entries[n] for n in self.names())

    def __contains__(self, name: object) -> bool:
        return name in self._entries

    def __getitem__(self, name: str) -> A:
        """The algorithm *name*; KeyError with the known names when it is unknown."""
        try:
            return self._entries[name]
        except KeyError:
            raise KeyError(self.unknown(name)) from None

    def unknown(self, name: object) -> str:
        """The sentence for an unknown name."""
        return f"unknown {self.kind} {name!r}; known: {', '.join(self.names())}"

    def parse(self, value: Any) -> BaseModel:
        """An algorithm's mapping ``{name: ..., <parameters>}`` validated by its model (a model instance passes)."""
        if isinstance(value, BaseModel):
            value = value.model_dump()
        if not isinstance(value, dict) or "name" not in value:
            raise PydanticCustomError(
                "algorithm_name",
                "a mapping with a name, one of: {known}",
                {"known": ", ".join(self.names())},
            )
        entry = self._entries.get(value["name"])
        if entry is None or entry.params is None:
            raise PydanticCustomError("unknown_algorithm", self.unknown(value["name"]))
        return entry.params.model_validate(value)

    def default(self, name: str) -> Callable[[], BaseModel]:
        """A default factory: the parameters of *name* at their defaults."""
        return lambda: self[name].params(name=name)

    def field(self) -> RegistryField:
        """The annotation's metadata of a configuration key holding one of these algorithms with its parameters."""
        return RegistryField(self)

    def name(self) -> RegistryName:
        """The annotation's metadata of a configuration key holding the name of one of these algorithms."""
        return RegistryName(self)

    def check(self, name: Any) -> str:
        """*name* when it is registered; a validation error listing the known names otherwise."""
        if name not in self._entries:
            raise PydanticCustomError("unknown_algorithm", self.unknown(name))
        return name

    def models(self) -> list[type[BaseModel]]:
        """The parameter models of the registered algorithms, in name order."""
        return [e.params for e in self if e.params is not None]


class RegistryField:
    """Validates a key by the registry (``Annotated[BaseModel, registry.field()]``); its schema lists the names.

    The models are looked up when a value is validated, so an algorithm
    registered after the configuration model was built is accepted.
    """

    def __init__(self, registry: Registry):
        self.registry = registry

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> core_schema.CoreSchema:
        return core_schema.no_info_plain_validator_function(
            self.registry.parse,
            serialization=core_schema.plain_serializer_function_ser_schema(
                lambda v, info: v.model_dump(mode=info.mode), info_arg=True
            ),
        )

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return {
            "type": "object",
            "required": ["name"],
            "properties": {"name": {"enum": self.registry.names()}},
            "description": f"a {self.registry.kind} and its parameters (docs/CONFIG.md)",
        }


class RegistryName:
    """Validates a key holding an algorithm's name by the registry (``Annotated[str, registry.name()]``)."""

    def __init__(self, registry: Registry):
        self.registry = registry

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> core_schema.CoreSchema:
        return core_schema.no_info_after_validator_function(self.registry.check, core_schema.str_schema())

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        return {"type": "string", "enum": self.registry.names()}
