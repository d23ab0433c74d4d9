"""One way to turn a pydantic validation error into the one line a user reads."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from edge.errors import describe_validation


class Inner(BaseModel):
    model_config = ConfigDict(extra="forbid")

    port: int = Field(default=1, ge=1)


class Outer(BaseModel):
    model_config = ConfigDict(extra="forbid")

    inner: Inner = Field(default_factory=Inner)
    names: list[str] = []

    @field_validator("names")
    @classmethod
    def _unique(cls, names: list[str]) -> list[str]:
        if len(set(names)) != len(names):
            raise ValueError("names must be unique")
        return names


@pytest.mark.parametrize(
    ("data", "top_level", "expected"),
    [
        ({"inner": {"port": 0}}, "(top level)", "inner.port: Input should be greater than or equal to 1"),
        ({"inner": {"prot": 2}}, "(top level)", "inner.prot: unknown key"),
        ({"names": ["a", "a"]}, "(top level)", "names: names must be unique"),  # no "Value error, " prefix
        ({"names": [1]}, "(top level)", "names.0: Input should be a valid string"),
        ([], "(body)", "(body): Input should be a valid dictionary or instance of Outer"),
        (
            {"inner": {"port": 0}, "extra": 1},
            "(top level)",
            "inner.port: Input should be greater than or equal to 1 (and 1 more)",
        ),
    ],
)
def test_the_first_error_names_its_key_and_counts_the_others(data: object, top_level: str, expected: str) -> None:
    with pytest.raises(ValidationError) as caught:
        Outer.model_validate(data)
    assert describe_validation(caught.value, top_level) == expected
