"""The SQLite schema of the record store, as the ordered migrations that build it.

A database at ``PRAGMA user_version`` v has had the first v migrations applied; opening it
applies the rest (:class:`controller.storage.db.CampaignStore`). A migration is never edited
once released: a change is a new one at the end.
"""

MIGRATIONS: tuple[str, ...] = (
    # v1: the record tables.
    """
    CREATE TABLE campaigns (
        id INTEGER PRIMARY KEY,
        name TEXT NOT NULL UNIQUE,
        config_path TEXT NOT NULL,
        config_sha256 TEXT NOT NULL,
        light_source TEXT NOT NULL,
        target TEXT NOT NULL,
        simulated INTEGER NOT NULL DEFAULT 0,
        queue_json TEXT NOT NULL,
        started_utc TEXT NOT NULL,
        finished_utc TEXT,
        status TEXT NOT NULL DEFAULT 'running',
        meta_json TEXT NOT NULL DEFAULT '{}'
    );
    CREATE TABLE heliostat_runs (
        id INTEGER PRIMARY KEY,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        heliostat_id TEXT NOT NULL,
        queue_index INTEGER NOT NULL,
        status TEXT NOT NULL,
        final_state TEXT NOT NULL,
        iterations INTEGER NOT NULL,
        error_before_mrad REAL,
        error_after_mrad REAL,
        true_error_before_mrad REAL,
        true_error_after_mrad REAL,
        matched_label TEXT,
        truth_label TEXT,
        fault_cause TEXT,
        fault_state TEXT,
        start_s REAL NOT NULL,
        at_standby_s REAL,
        on_target_s REAL,
        off_target_s REAL,
        end_s REAL NOT NULL,
        finished_utc TEXT NOT NULL,
        UNIQUE (campaign_id, heliostat_id)
    );
    CREATE TABLE measurements (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        iteration INTEGER NOT NULL,
        az_steps INTEGER NOT NULL,
        el_steps INTEGER NOT NULL,
        source_e REAL NOT NULL, source_n REAL NOT NULL, source_u REAL NOT NULL,
        source_az_deg REAL NOT NULL,
        source_el_deg REAL NOT NULL,
        centroid_e REAL, centroid_n REAL, centroid_u REAL,
        centroid_x_px REAL, centroid_y_px REAL,
        aim_e REAL NOT NULL, aim_n REAL NOT NULL, aim_u REAL NOT NULL,
        error_mrad REAL,
        true_error_mrad REAL,
        matched_label TEXT,
        match_distance REAL,
        runner_up_label TEXT,
        runner_up_distance REAL,
        plant_time_s REAL NOT NULL,
        measured_utc TEXT NOT NULL,
        UNIQUE (run_id, iteration)
    );
    CREATE TABLE corrections (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        iteration INTEGER NOT NULL,
        kind TEXT NOT NULL CHECK (kind IN ('coarse', 'fine')),
        daz_deg REAL NOT NULL,
        del_deg REAL NOT NULL,
        daz_steps INTEGER NOT NULL,
        del_steps INTEGER NOT NULL
    );
    CREATE TABLE model_params (
        id INTEGER PRIMARY KEY,
        heliostat_id TEXT NOT NULL,
        campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        params_json TEXT NOT NULL,
        sigma_json TEXT NOT NULL,
        residual_mrad REAL,
        n_measurements INTEGER NOT NULL,
        created_utc TEXT NOT NULL
    );
    CREATE TABLE images (
        id INTEGER PRIMARY KEY,
        measurement_id INTEGER NOT NULL REFERENCES measurements(id),
        kind TEXT NOT NULL,
        path TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        exposure_low_s REAL NOT NULL,
        exposure_high_s REAL NOT NULL
    );
    CREATE INDEX measurements_run ON measurements(run_id);
    CREATE INDEX model_params_heliostat ON model_params(heliostat_id, id);
    """,
    # v2: the record store holds what the controller measured, nothing a simulator knows. The
    # simulated plant keeps its truth in its own table (simplant.harness, ``sim_truth``).
    """
    ALTER TABLE campaigns DROP COLUMN simulated;
    ALTER TABLE heliostat_runs DROP COLUMN true_error_before_mrad;
    ALTER TABLE heliostat_runs DROP COLUMN true_error_after_mrad;
    ALTER TABLE heliostat_runs DROP COLUMN truth_label;
    ALTER TABLE measurements DROP COLUMN true_error_mrad;
    """,
    # v3: why a campaign ended as it did (status finished / partial / aborted / interrupted).
    """
    ALTER TABLE campaigns ADD COLUMN cause TEXT;
    """,
    # v4: the tracking model's covariance and identified terms.
    """
    ALTER TABLE model_params ADD COLUMN detail_json TEXT;
    """,
    # v5: the nightly planner's choices and why (controller.calibration.night.planner).
    """
    CREATE TABLE plan (
        id INTEGER PRIMARY KEY,
        night TEXT NOT NULL,
        heliostat_id TEXT NOT NULL,
        rank INTEGER NOT NULL,
        strategy TEXT NOT NULL,
        lamp TEXT NOT NULL,
        aim_e REAL NOT NULL, aim_n REAL NOT NULL, aim_u REAL NOT NULL,
        cell_row INTEGER NOT NULL, cell_col INTEGER NOT NULL,
        az_steps INTEGER NOT NULL, el_steps INTEGER NOT NULL,
        expected_gain REAL NOT NULL,
        predicted_before_mrad REAL NOT NULL,
        predicted_after_mrad REAL NOT NULL,
        created_utc TEXT NOT NULL,
        UNIQUE (night, heliostat_id, rank)
    );
    CREATE INDEX plan_night ON plan(night);
    """,
    # v6: where a lamp stood (its direction from the mirror depends on the mirror's position).
    """
    ALTER TABLE measurements ADD COLUMN source_pos_e REAL;
    ALTER TABLE measurements ADD COLUMN source_pos_n REAL;
    ALTER TABLE measurements ADD COLUMN source_pos_u REAL;
    """,
    # v7: several targets in parallel: the target each measurement and planned geometry was on
    # (earlier measurements were on their campaign's target; earlier plans on the calibration
    # target, left NULL).
    """
    ALTER TABLE measurements ADD COLUMN target TEXT;
    UPDATE measurements SET target = (SELECT c.target FROM heliostat_runs r JOIN campaigns c
                                      ON c.id = r.campaign_id WHERE r.id = measurements.run_id);
    ALTER TABLE plan ADD COLUMN target TEXT;
    """,
    # v8: nights. The calibration campaign of a field is night 0, each planned night the next
    # (its passes are the campaigns named "<night>/..."); the index drives nothing in the
    # product but tells the operator, the report and a simulated plant which night it is.
    """
    CREATE TABLE nights (
        id INTEGER PRIMARY KEY,
        idx INTEGER NOT NULL UNIQUE,
        name TEXT NOT NULL UNIQUE,
        kind TEXT NOT NULL CHECK (kind IN ('calibration', 'planned')),
        started_utc TEXT NOT NULL,
        finished_utc TEXT,
        status TEXT NOT NULL DEFAULT 'running',
        cause TEXT,
        summary_json TEXT NOT NULL DEFAULT '{}'
    );
    CREATE INDEX campaigns_name ON campaigns(name);
    """,
    # v9: a field of thousands of heliostats. Indices for the queries of a night, its morning
    # report and the console (a heliostat's runs and measurements, a run's corrections, a
    # measurement's images), and what each heliostat of a planned night ended with: where it
    # stands, its geometries planned and measured, the daytime error its model predicts and, when
    # it had none, why no geometry was measurable.
    """
    CREATE INDEX heliostat_runs_heliostat ON heliostat_runs(heliostat_id, id);
    CREATE INDEX corrections_run ON corrections(run_id);
    CREATE INDEX images_measurement ON images(measurement_id);
    CREATE TABLE night_heliostats (
        night_id INTEGER NOT NULL REFERENCES nights(id),
        heliostat_id TEXT NOT NULL,
        east_m REAL NOT NULL,
        north_m REAL NOT NULL,
        planned INTEGER NOT NULL,
        measured INTEGER NOT NULL,
        predicted_rms_mrad REAL,
        unmeasurable TEXT,
        PRIMARY KEY (night_id, heliostat_id)
    );
    """,
    # v10: records imported from another system's files (``heliocal import paint``): the file
    # each measurement came from (its heliostat and record id, the bytes' SHA-256), so that a
    # re-import adds only new records, and the focal-spot method it holds.
    """
    CREATE TABLE imported_records (
        measurement_id INTEGER PRIMARY KEY REFERENCES measurements(id),
        source TEXT NOT NULL,
        heliostat_id TEXT NOT NULL,
        record_id TEXT NOT NULL,
        method TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        UNIQUE (source, heliostat_id, record_id)
    );
    """,
    # v11: operations (issue 40), one self-contained migration; its tables are found by name, not by
    # this migration's number (storage modules check the table, never user_version):
    # * lamp_states: every lamp as each night or campaign left it (lights out at every end),
    #   what an alarm list reads; state dark (confirmed by the panel), lit (still confirmed lit),
    #   no_answer (the panel could not tell), operator (no panel: the operator was asked);
    # * field_prints: what each heliostat's model was fitted on (its position and kinematics, each
    #   target's frame), so a model is never applied to another field;
    # * geometry_failures: a planned geometry tried and not measured, per night; two nights flag
    #   it (not planned again) until it is cleared;
    # * run_frames: the frames of a capture that gave no measurement (no beam, a clipped spot).
    """
    CREATE TABLE lamp_states (
        id INTEGER PRIMARY KEY,
        session TEXT NOT NULL,
        ended TEXT NOT NULL,
        channel TEXT NOT NULL,
        state TEXT NOT NULL CHECK (state IN ('dark', 'lit', 'no_answer', 'operator')),
        commanded INTEGER,
        detail TEXT,
        checked_utc TEXT NOT NULL
    );
    CREATE INDEX lamp_states_state ON lamp_states(state, id);
    CREATE TABLE field_prints (
        subject TEXT PRIMARY KEY,
        keys_json TEXT NOT NULL,
        config_path TEXT NOT NULL,
        config_sha256 TEXT NOT NULL,
        recorded_utc TEXT NOT NULL
    );
    CREATE TABLE geometry_failures (
        id INTEGER PRIMARY KEY,
        night TEXT NOT NULL,
        heliostat_id TEXT NOT NULL,
        lamp TEXT NOT NULL,
        target TEXT NOT NULL,
        cell_row INTEGER NOT NULL,
        cell_col INTEGER NOT NULL,
        status TEXT NOT NULL,
        cause TEXT,
        recorded_utc TEXT NOT NULL,
        cleared_utc TEXT,
        UNIQUE (night, heliostat_id, lamp, target, cell_row, cell_col)
    );
    CREATE TABLE run_frames (
        id INTEGER PRIMARY KEY,
        run_id INTEGER NOT NULL REFERENCES heliostat_runs(id),
        kind TEXT NOT NULL,
        path TEXT NOT NULL,
        sha256 TEXT NOT NULL,
        exposure_low_s REAL NOT NULL,
        exposure_high_s REAL NOT NULL
    );
    CREATE INDEX run_frames_run ON run_frames(run_id);
    """,
    # Plant integration (docs/plant-integration.md): the alarm list (one row per condition and
    # source, its ISA-18.2 state) and its history (never rewritten), the operator accounts (scrypt
    # password hashes, roles) and the audit trail of who did what.
    """
    CREATE TABLE alarms (
        id INTEGER PRIMARY KEY,
        condition TEXT NOT NULL,
        source TEXT NOT NULL,
        message TEXT NOT NULL,
        active INTEGER NOT NULL,
        acked INTEGER NOT NULL,
        raised_utc TEXT NOT NULL,
        count INTEGER NOT NULL DEFAULT 1,
        cleared_utc TEXT,
        acked_utc TEXT,
        acked_by TEXT,
        ack_comment TEXT,
        shelved_until_utc TEXT,
        shelved_by TEXT,
        UNIQUE (condition, source)
    );
    CREATE TABLE alarm_events (
        id INTEGER PRIMARY KEY,
        alarm_id INTEGER NOT NULL REFERENCES alarms(id),
        time_utc TEXT NOT NULL,
        kind TEXT NOT NULL CHECK (kind IN ('raised', 'cleared', 'acknowledged', 'shelved', 'unshelved')),
        user TEXT,
        message TEXT NOT NULL
    );
    CREATE INDEX alarm_events_alarm ON alarm_events(alarm_id, id);
    CREATE TABLE users (
        name TEXT PRIMARY KEY,
        role TEXT NOT NULL CHECK (role IN ('viewer', 'operator', 'engineer')),
        password_hash TEXT NOT NULL,
        created_utc TEXT NOT NULL
    );
    CREATE TABLE audit (
        id INTEGER PRIMARY KEY,
        time_utc TEXT NOT NULL,
        user TEXT NOT NULL,
        action TEXT NOT NULL,
        target TEXT NOT NULL DEFAULT '',
        detail TEXT NOT NULL DEFAULT ''
    );
    CREATE INDEX audit_time ON audit(time_utc);
    """,
    # v12: a heliostat's beam search (issue 46, calibration.search; storage/searches.py): looks
    # taken, points skipped, plant seconds, found or not, where the starting pose's beam landed
    # (u, v m from the aim point) and the offsets looked at (JSON [[u, v], ...]).
    """
    CREATE TABLE beam_searches (
        run_id INTEGER PRIMARY KEY REFERENCES heliostat_runs(id),
        looks INTEGER NOT NULL,
        skipped INTEGER NOT NULL,
        seconds REAL NOT NULL,
        found INTEGER NOT NULL,
        miss_u_m REAL,
        miss_v_m REAL,
        offsets_json TEXT NOT NULL
    );
    """,
)

SCHEMA_VERSION = len(MIGRATIONS)
