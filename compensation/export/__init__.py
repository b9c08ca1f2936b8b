"""Controller compensation tables from an error model, each checked against the model before writing.

One export for every machine tool (a ``kind = "grinder"`` file is read as its chain): three table formats of
a volumetric error model (:data:`FORMATS`: ``iso-tables`` :mod:`.iso_tables`, ``grid`` :mod:`.grid`,
``linuxcnc`` :mod:`.linuxcnc`) and a drift model's coefficients (``drift``, :mod:`.drift`), each with a
writer, a reader and a *controller simulation*, so that the check reports, before anything is written, the
error the table leaves (docs/reference/controller-tables.md). The model and truth: :mod:`.model`,
:mod:`.sources`; the check and the sizing: :mod:`.check`; the staged write: :mod:`.common`. The command:
:mod:`compensation.app.commands.export`."""
from .check import (build_checked_table, build_table, check_export, check_sets, point_set, read_back,
                    table_difference_um, volume_points, worst_model_um, write_table)
from .common import (ALL_FORMATS, LINUXCNC_MAX_POINTS, TableField, staged_folder, table_bytes, weighted_node_means,
                     write_manifest)
from .drift import (DRIFT_FILE, DRIFT_MAX_PERIOD_S, DRIFT_TICK_EPS_S, check_drift_export, controller_drift,
                    controller_drift_at, drift_coefficients, drift_distance_rule, export_drift_coefficients,
                    read_drift_coefficients, worst_drift_model_um, write_drift_coefficients)
from .grid import grid_from_model, read_grid, write_grid
from .iso_tables import iso_tables_from_model, write_iso_tables
from .linuxcnc import JointTables, joint_tables_from_model, read_joint_tables, write_joint_tables
from .model import TABLE_TEMP_C, ModelError
from .sources import (CHECKS_DIAGNOSIS_FORMAT, backlash_from_diagnosis, chain_truth_tool_points, load_model,
                      reversal_from_diagnosis, truth_tool_points)

__all__ = ["ALL_FORMATS", "backlash_from_diagnosis", "build_checked_table", "build_table", "chain_truth_tool_points",
           "check_drift_export", "check_export", "check_sets", "CHECKS_DIAGNOSIS_FORMAT", "controller_drift",
           "controller_drift_at", "drift_coefficients", "drift_distance_rule", "DRIFT_FILE", "DRIFT_MAX_PERIOD_S",
           "DRIFT_TICK_EPS_S", "export_drift_coefficients", "grid_from_model", "iso_tables_from_model",
           "joint_tables_from_model", "JointTables", "LINUXCNC_MAX_POINTS", "load_model", "ModelError", "point_set",
           "read_back", "read_drift_coefficients", "read_grid", "read_joint_tables", "reversal_from_diagnosis",
           "staged_folder", "table_bytes", "table_difference_um", "TABLE_TEMP_C", "TableField", "truth_tool_points",
           "volume_points", "weighted_node_means", "worst_drift_model_um", "worst_model_um", "write_drift_coefficients",
           "write_grid", "write_iso_tables", "write_joint_tables", "write_manifest", "write_table"]
