"""Objects named ``"package.module:attribute"``, imported when asked: how the registries point at the body for a
kind (the verbs' handlers, the scenario kinds' loaders, the drivers a scenario names) without importing it first
(``olti --help`` stays fast). Only the standard library."""

import importlib


def resolve(where: str):
    """The attribute ``where`` = ``"package.module:attribute"`` names (its module imported now)."""
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)
