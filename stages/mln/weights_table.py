"""A weights.parquet table read for people: its strongest formulas (the learn-weights summary, the report's
Table II)."""

from __future__ import annotations

import polars as pl


def strongest(weights: pl.DataFrame, per_class: int = 3) -> pl.DataFrame:
    """The ``per_class`` largest weights of each class among the per-frame formulas (hard formulas first); classes
    in the order they first appear."""
    per_frame = weights.filter(~pl.col("temporal")) if "temporal" in weights.columns else weights
    per_frame = per_frame.filter(pl.col("class").is_not_null())
    order = {name: i for i, name in enumerate(dict.fromkeys(per_frame["class"].to_list()))}
    return (
        per_frame.with_columns(pl.col("class").replace_strict(order, return_dtype=pl.Int64).alias("_order"))
        .sort(["_order", "hard", "weight"], descending=[False, True, True]).drop("_order")
        .group_by("class", maintain_order=True).head(per_class)
    )


def strongest_temporal(weights: pl.DataFrame, count: int = 5) -> pl.DataFrame:
    """The hard temporal formulas, then the ``count`` temporal formulas of largest |weight|."""
    if "temporal" not in weights.columns:
        return weights.clear()
    temporal = weights.filter(pl.col("temporal"))
    return pl.concat([temporal.filter(pl.col("hard")),
                      temporal.filter(~pl.col("hard")).sort(pl.col("weight").abs(), descending=True).head(count)])
