"""The base of every model a user writes (a scene, a kind's config and each part nested in it): a key it
does not declare is an error naming it, not a value silently dropped. Pydantic's default ignores such keys,
so a misspelt `train.stpes` ran the default step count and, equal to an earlier job once dropped, was
answered with that old job. It lives in the lowest layer so that every layer's models can share it.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class StrictModel(BaseModel):
    model_config = ConfigDict(extra="forbid")
