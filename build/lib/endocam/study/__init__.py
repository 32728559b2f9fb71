"""The video-based skill-assessment study (paper Sec. IV-D and V).

- :mod:`~endocam.study.manifest`: the study folder's ``manifest.json`` (the contract with
  ``endocam study make``);
- :mod:`~endocam.study.counterbalance`: Williams-design presentation orders, round-robin assignment;
- :mod:`~endocam.study.flow`: a participant's path through the sets and the attention question;
- :mod:`~endocam.study.db`: the SQLite store, :mod:`~endocam.study.records` its records;
  :mod:`~endocam.study.app`: the web app (``study`` extra), :mod:`~endocam.study.admin_auth` its
  admin sign-in;
- :mod:`~endocam.study.analysis` and :mod:`~endocam.study.report`: statistics and outputs.
"""

from endocam.study.analysis import AnalysisConfig, AnalysisResult, OutlierRule, analyze
from endocam.study.counterbalance import assign_order, presentation_orders, williams_design
from endocam.study.manifest import (
    AttentionQuestion,
    Condition,
    Manifest,
    ManifestError,
    Video,
    load_manifest,
    parse_manifest,
)
from endocam.study.responses import ResponseRow, read_responses_csv, rows_from_csv, rows_to_csv

__all__ = [
    "AnalysisConfig",
    "AnalysisResult",
    "AttentionQuestion",
    "Condition",
    "Manifest",
    "ManifestError",
    "OutlierRule",
    "ResponseRow",
    "Video",
    "analyze",
    "assign_order",
    "load_manifest",
    "parse_manifest",
    "presentation_orders",
    "read_responses_csv",
    "rows_from_csv",
    "rows_to_csv",
    "williams_design",
]
