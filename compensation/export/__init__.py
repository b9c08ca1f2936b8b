"""Controller compensation tables from an error model, each checked against the model before writing.

One export for every machine tool (a ``kind = "grinder"`` file is read as its chain): three table formats of
a volumetric error model (:data:`FORMATS`: ``iso-tables`` :mod:`.iso_tables`, ``grid`` :mod:`.grid`,
``linuxcnc`` :mod:`.linuxcnc`) and a drift model's coefficients (``drift``, :mod:`.drift`), each with a
writer, a reader and a *controller simulation*, so that the check reports, before anything is written, the
error the table leaves (docs/reference/controller-tables.md). The model and truth: :mod:`.model`,
:mod:`.sources`; the check and the sizing: :mod:`.check`; the staged write: :mod:`.common`. The command:
:mod:`compensation.app.commands.export`.

The names below load lazily (their module on first use): ``volcomp export`` reads its options' choices and
limits (:mod:`.common`, :mod:`.drift`) without the check's kernels."""
from errormap import lazy_exports

_MODULES = {  # submodule: the names it exports here
    "check": ("build_checked_table", "build_table", "check_export", "check_sets", "point_set", "read_back",
              "table_difference_um", "volume_points", "worst_model_um", "write_table"),
    "common": ("ALL_FORMATS", "LINUXCNC_MAX_POINTS", "TableField", "staged_folder", "table_bytes",
               "weighted_node_means", "write_manifest"),
    "drift": ("DRIFT_FILE", "DRIFT_MAX_PERIOD_S", "DRIFT_TICK_EPS_S", "check_drift_export", "controller_drift",
              "controller_drift_at", "drift_coefficients", "drift_distance_rule", "export_drift_coefficients",
              "read_drift_coefficients", "worst_drift_model_um", "write_drift_coefficients"),
    "grid": ("grid_from_model", "read_grid", "write_grid"),
    "iso_tables": ("iso_tables_from_model", "write_iso_tables"),
    "linuxcnc": ("JointTables", "joint_tables_from_model", "read_joint_tables", "write_joint_tables"),
    "model": ("TABLE_TEMP_C", "ModelError"),
    "sources": ("CHECKS_DIAGNOSIS_FORMAT", "backlash_from_diagnosis", "chain_truth_tool_points", "load_model",
                "reversal_from_diagnosis", "truth_tool_points"),
}
_LAZY = {name: f"compensation.export.{module}" for module, names in _MODULES.items() for name in names}

__all__ = sorted(_LAZY)

__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
