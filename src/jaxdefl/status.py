"""The status vocabularies: of a window (and of a plate or axis left out), one enum for every
stage; of a campaign unit, one enum for the manifests, the runner and the reports.

A `Status` is a `str`, so tables, JSON and comparisons with plain strings keep working; code
names its members instead of spelling the strings.
"""

from enum import StrEnum

__all__ = ["Status", "STATUSES", "UnitStatus"]


class Status(StrEnum):
    CONVERGED = "converged"
    TOO_FEW_SAMPLES = "too_few_samples"  # fewer samples than the model needs (or none valid)
    TOO_FEW_CYCLES = "too_few_cycles"  # the peak frequency times the span is below the minimum
    NO_SIGNIFICANT_PEAK = "no_significant_peak"  # false-alarm probability above the maximum
    DID_NOT_CONVERGE = "did_not_converge"  # Gauss-Newton failed or gave non-finite numbers
    VALUE_OUT_OF_RANGE = "value_out_of_range"  # a value beyond MAX_ABS_VALUE_MM
    ABSENT = "absent"  # no such window in a campaign unit (the campaign dataset's filler)


STATUSES = tuple(s.value for s in Status)


class UnitStatus(StrEnum):
    """The outcome of a campaign unit (its manifest's ``status``)."""

    OK = "ok"
    FAILED = "failed"
