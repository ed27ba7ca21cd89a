"""Episode records: the schema, the labels, the records file, and the rules that read a record.

One episode gives one :class:`EpisodeRecord`; experiments store one JSON object per line in
``episodes.jsonl`` (:data:`RECORDS_FILE`). Every part of the package that reads records
(the experiment runner's store, the tables, the report, the sweeps) reads the file with
:func:`read_records` and judges a record with the rules below, so that a rate means the
same wherever it is printed or drawn. ::

    from cdf_mj.records import avoided, is_imminent, load_records
    records = load_records("results/reproduce")        # dicts, one per line
    cutoffs = [r for r in records if is_imminent(r)]
    share = sum(map(avoided, cutoffs)) / len(cutoffs)

The package's modules: :mod:`~cdf_mj.records.schema` (the record, its labels, the check
of every line), :mod:`~cdf_mj.records.counting` (the rules below) and
:mod:`~cdf_mj.records.files` (the records and settings files, atomic writes); every name is
re-exported here.

The rules take a record as a dict (a line of the file, or :meth:`EpisodeRecord.to_dict`)
or as an :class:`EpisodeRecord`:

====================  ========================================================================
:func:`is_imminent`   the episode is labelled Cutoff (the paper's "collision imminent")
:func:`hit_obstacle`  the ego touched the obstacle, whatever the label (the paper's "collision
                      occurred")
:func:`avoided`       a Cutoff episode without a collision with the obstacle
:func:`braked`        the planner decided to brake
:func:`is_false_alarm` a labelled episode not labelled Cutoff in which the planner braked (a
                      hard-brake false alarm)
:func:`intervened`    the planner held the ego below its own controller by more than the
                      tolerance on some tick (None: a record without ``intervention``)
:func:`is_false_intervention` an intervention in a labelled episode not labelled Cutoff
:func:`pass_time`     [s] the ego passed ``timing.label_distance`` beyond the conflict point
:func:`lead_time`     [s] obstacle enters the ego lane - brake decision, in a braking Cutoff
                      episode
:func:`prediction`    the planner's predicted label
:func:`paper_avoided` the paper's count, (imminent - occurred) / imminent
====================  ========================================================================
"""

from cdf_mj.records.counting import (
    avoided,
    braked,
    completed,
    hit_obstacle,
    intervened,
    is_false_alarm,
    is_false_intervention,
    is_imminent,
    lead_time,
    paper_avoided,
    pass_time,
    prediction,
    record_field,
)
from cdf_mj.records.files import (
    RECORDS_FILE,
    SETTINGS_FILE,
    RecordsFile,
    check_settings,
    fsync_directory,
    jsonable,
    load_records,
    read_records,
    read_settings,
    write_atomic,
)
from cdf_mj.records.schema import (
    FAILED,
    INTERVENTION_KEYS,
    LABELS,
    OK,
    EpisodeRecord,
    Label,
    Labels,
    RecordLike,
    check_record,
)

__all__ = ["FAILED", "INTERVENTION_KEYS", "LABELS", "OK", "RECORDS_FILE", "SETTINGS_FILE", "EpisodeRecord", "Label",
           "Labels", "RecordLike", "RecordsFile", "avoided", "braked", "check_record", "check_settings", "completed",
           "fsync_directory", "hit_obstacle", "intervened", "is_false_alarm", "is_false_intervention", "is_imminent",
           "jsonable", "lead_time", "load_records", "paper_avoided", "pass_time", "prediction", "read_records",
           "read_settings", "record_field", "write_atomic"]
