// The whole flow of a spacearm client in TypeScript, type-checked with `tsc --strict` against the
// types openapi-typescript generates from the live OpenAPI document (generated/spacearm.ts) and
// run with node against a live API (tests/service/test_generated_client.py): copy the paper's
// robot (and once more from its URDF), plan the paper's task preset, read the plan back, download
// its figures, submit a small tuning job, poll it to completion, read its result and its event
// stream, download its convergence figure, then delete the plan, the job and the robots.
// Usage: node build/flow.js <base URL>; prints a JSON summary on stdout.
import createClient from "openapi-fetch";

import type { components, paths } from "./generated/spacearm.js";

type Schemas = components["schemas"];

// Compile-time checks of the document: always-present response fields are required (a client
// reads them without `undefined`), closed vocabularies are unions of literals, method and robot
// parameters are typed objects.
type IsRequired<T, K extends keyof T> = object extends Pick<T, K> ? false : true;
type Equal<A, B> = (<T>() => T extends A ? 1 : 2) extends <T>() => T extends B ? 1 : 2 ? true : false;
const typeChecks: [
    IsRequired<Schemas["PlanOut"], "metrics">,
    IsRequired<Schemas["PlanOut"], "method">,
    IsRequired<Schemas["PlanMetrics"], "max_joint_speed_deg_s">,
    IsRequired<Schemas["TuningJobOut"], "progress">,
    IsRequired<Schemas["TuningJobOut"], "links">,
    IsRequired<Schemas["JobProgress"], "phases">,
    IsRequired<Schemas["TuningJobResult"], "dls_baseline">,
    IsRequired<Schemas["TuningJobResult"], "warnings">,
    IsRequired<Schemas["RobotOut"], "parameters">,
    Equal<Schemas["RobotOut"]["parameters"], Schemas["RobotParams"]>,
    IsRequired<Schemas["RobotOut"], "joints">,
    Equal<Schemas["JointOut"]["type"], "revolute" | "prismatic">,
    Equal<Schemas["MethodName"], "inverse" | "dls" | "adaptive" | "wdls" | "sdls" | "svf" | "bounded">,
    Equal<Schemas["JobStatus"], "queued" | "running" | "succeeded" | "failed" | "cancelled">,
    Equal<Schemas["AggregationName"], "max" | "rms" | "final">,
    Equal<Schemas["AttitudeTermName"], "angle" | "eq18">,
    Equal<Schemas["TimeProfile"], "trapezoidal" | "quintic">,
    Equal<Schemas["PhaseRole"], "tuned" | "dls_baseline" | "bounded_baseline" | "nominal_tuned">,
    Equal<Schemas["MethodOut"]["params"]["lambda_max"], number | undefined>,
    // a request's defaulted field may be left out
    Equal<IsRequired<Schemas["TaskIn"], "dt_s">, false>,
    IsRequired<Schemas["PlanOut"], "request">,
    IsRequired<Schemas["TuningJobOut"], "worker_id">,
    Equal<Schemas["TrajectoryFormat"], "json" | "csv" | "mat" | "npz" | "ros">,
    Equal<Schemas["ResultStatus"], "succeeded" | "cancelled">,
] = [
    true, true, true, true, true, true, true, true, true, true, true, true,
    true, true, true, true, true, true, true, true, true, true, true, true,
];

const FINISHED: ReadonlySet<Schemas["JobStatus"]> = new Set(["succeeded", "failed", "cancelled"]);

function fail(what: string, detail: unknown): never {
    throw new Error(`${what}: ${JSON.stringify(detail)}`);
}

/** What a figure's bytes are: `svg`, `png` or `unknown`. */
async function figureKind(blob: Blob): Promise<string> {
    const head = new Uint8Array(await blob.slice(0, 512).arrayBuffer());
    if (head[0] === 0x89 && String.fromCharCode(...head.slice(1, 4)) === "PNG") return "png";
    return new TextDecoder().decode(head).includes("<svg") ? "svg" : "unknown";
}

async function main(baseUrl: string): Promise<void> {
    const client = createClient<paths>({ baseUrl });

    // a robot of our own: the paper's parameters (typed RobotParams), stored again
    const table1 = await client.GET("/v1/robots/{robot_id}", { params: { path: { robot_id: "table1" } } });
    if (table1.error !== undefined) fail("get_robot", table1.error);
    const robotParams: Schemas["RobotParams"] = { ...table1.data.parameters, name: "typescript copy" };
    const robotCreated = await client.POST("/v1/robots", { body: robotParams });
    if (robotCreated.error !== undefined) fail("create_robot", robotCreated.error);
    const robot: Schemas["RobotOut"] = robotCreated.data;
    // and once more from its URDF (text), stored as another robot
    const urdf = await client.GET("/v1/robots/{robot_id}/urdf", { params: { path: { robot_id: robot.id } }, parseAs: "text" });
    if (urdf.error !== undefined) fail("get_robot_urdf", urdf.error);
    const urdfBody: Schemas["RobotUrdfIn"] = { urdf: urdf.data, name: "typescript urdf copy" };
    const fromUrdf = await client.POST("/v1/robots", { body: urdfBody });
    if (fromUrdf.error !== undefined) fail("create_robot (urdf)", fromUrdf.error);

    // the paper's task preset, planned with adaptive damping
    const preset = await client.GET("/v1/task-presets/{name}", { params: { path: { name: "paper-line" } } });
    if (preset.error !== undefined) fail("get_task_preset", preset.error);
    const task: Schemas["TaskIn"] = preset.data.task;
    const planRequest: Schemas["PlanRequestStoredRobot"] = {
        robot_id: robot.id,
        task,
        method: { name: "adaptive", params: { lambda_max: 0.06, epsilon: 0.12 } },
        aggregation: "max",
    };
    const created = await client.POST("/v1/plans", { body: planRequest, params: { query: { fields: "replay" } } });
    if (created.error !== undefined) fail("create_plan", created.error);
    const plan: Schemas["PlanOut"] = created.data;

    const read = await client.GET("/v1/plans/{plan_id}", { params: { path: { plan_id: plan.id }, query: { fields: "" } } });
    if (read.error !== undefined) fail("get_plan", read.error);
    // what it was asked, the list filtered by method, the plan again with changes (a merge patch)
    const asked: Schemas["PlanRequest"] | null = read.data.request;
    const listed = await client.GET("/v1/plans", { params: { query: { method: "adaptive", path_type: "line", success: true } } });
    if (listed.error !== undefined) fail("list_plans", listed.error);
    const rerunBody: Schemas["PlanRerun"] = { from_plan_id: plan.id, method: { name: "dls" }, replay: false };
    const rerun = await client.POST("/v1/plans", { body: rerunBody, params: { query: { fields: "" } } });
    if (rerun.error !== undefined) fail("create_plan (from_plan_id)", rerun.error);
    // the trajectory as CSV (text) and as a ROS JointTrajectory (typed JSON)
    const csv = await client.GET("/v1/plans/{plan_id}/trajectory", {
        params: { path: { plan_id: plan.id }, query: { format: "csv" } },
        parseAs: "text",
    });
    if (csv.error !== undefined) fail("get_plan_trajectory (csv)", csv.error);
    const ros = await client.GET("/v1/plans/{plan_id}/trajectory", {
        params: { path: { plan_id: plan.id }, query: { format: "ros" } },
        headers: { Accept: "application/vnd.spacearm.ros-joint-trajectory+json" },
        parseAs: "json",
    });
    if (ros.error !== undefined) fail("get_plan_trajectory (ros)", ros.error);
    const rosTrajectory = ros.data as Schemas["RosJointTrajectory"];

    const svg = await client.GET("/v1/plans/{plan_id}/figures/{name}", {
        params: { path: { plan_id: plan.id, name: "joint-angles" }, query: { format: "svg" } },
        parseAs: "blob",
    });
    if (svg.error !== undefined) fail("get_plan_figure", svg.error);
    const png = await client.GET("/v1/plans/{plan_id}/figures/{name}", {
        params: { path: { plan_id: plan.id, name: "scene-3d" }, query: { format: "png" } },
        parseAs: "blob",
    });
    if (png.error !== undefined) fail("get_plan_figure", png.error);

    // a small tuning job on the same robot and task
    const jobRequest: Schemas["TuningJobRequestStoredRobot"] = {
        robot_id: robot.id,
        tasks: [task],
        method: "adaptive",
        bounds: { lambda_max: [0.0001, 0.2], epsilon: [0.0001, 1.0] },
        ga: { population: 4, generations: 2, seed: 1 },
        objective: { weights: [0.5, 0.5], aggregation: "max", attitude_term: "eq18" },
        refine: false, // the paper's GA alone: the flow counts its three generations
    };
    const submitted = await client.POST("/v1/tuning-jobs", { body: jobRequest });
    if (submitted.error !== undefined) fail("create_tuning_job", submitted.error);
    let job: Schemas["TuningJobOut"] = submitted.data;
    const deadline = Date.now() + 120_000;
    while (!FINISHED.has(job.status) && Date.now() < deadline) {
        await new Promise((resolve) => setTimeout(resolve, 100));
        const polled = await client.GET("/v1/tuning-jobs/{job_id}", { params: { path: { job_id: job.id } } });
        if (polled.error !== undefined) fail("get_tuning_job", polled.error);
        job = polled.data;
    }
    const result = await client.GET("/v1/tuning-jobs/{job_id}/result", { params: { path: { job_id: job.id } } });
    if (result.error !== undefined) fail("get_tuning_job_result", result.error);
    const tuned: Schemas["TuningJobResult"] = result.data;
    const resultStatus: Schemas["ResultStatus"] = tuned.status;
    const events = await client.GET("/v1/tuning-jobs/{job_id}/events", {
        params: { path: { job_id: job.id } },
        parseAs: "text",
    });
    if (events.error !== undefined) fail("get_tuning_job_events", events.error);
    const convergence = await client.GET("/v1/tuning-jobs/{job_id}/figures/{name}", {
        params: { path: { job_id: job.id, name: "convergence" }, query: { format: "png" } },
        parseAs: "blob",
    });
    if (convergence.error !== undefined) fail("get_tuning_job_figure", convergence.error);

    // deletion, then the plan is a 404 problem
    const deletedPlan = await client.DELETE("/v1/plans/{plan_id}", { params: { path: { plan_id: plan.id } } });
    const deletedJob = await client.DELETE("/v1/tuning-jobs/{job_id}", { params: { path: { job_id: job.id } } });
    const deletedRobot = await client.DELETE("/v1/robots/{robot_id}", { params: { path: { robot_id: robot.id } } });
    await client.DELETE("/v1/robots/{robot_id}", { params: { path: { robot_id: fromUrdf.data.id } } });
    const missing = await client.GET("/v1/plans/{plan_id}", { params: { path: { plan_id: plan.id } } });
    const problem: Schemas["Problem"] | undefined = missing.error;

    const summary = {
        type_checks: typeChecks.length,
        robot_status: robotCreated.response.status,
        robot_location: robotCreated.response.headers.get("Location"),
        robot_id: robot.id,
        robot_links: robot.parameters.links.length,
        robot_joint_types: robot.joints.map((j) => j.type),
        urdf_robot_joints: fromUrdf.data.n_joints,
        task_dt_s: task.dt_s ?? null,
        plan_id: plan.id,
        plan_status: created.response.status,
        plan_location: created.response.headers.get("Location"),
        plan_method: plan.method.name,
        plan_params: plan.method.params,
        plan_success: plan.success,
        attitude_term: plan.metrics.attitude_term,
        max_joint_speed_deg_s: plan.metrics.max_joint_speed_deg_s,
        has_trajectory: plan.trajectory !== undefined,
        replay_success: plan.replay?.success ?? null,
        asked_method: asked?.method?.name ?? null,
        listed_has_plan: listed.data.items.some((p) => p.id === plan.id),
        rerun_method: rerun.data.method.name,
        rerun_asked_method: rerun.data.request?.method ?? null,
        csv_rows: csv.data.trim().split("\n").length,
        ros_joints: rosTrajectory.joint_names.length,
        ros_points: rosTrajectory.points.length,
        job_worker: job.worker_id,
        result_status: resultStatus,
        read_back_id: read.data.id,
        read_back_keys: Object.keys(read.data).sort(),
        plan_svg: { kind: await figureKind(svg.data), type: svg.response.headers.get("Content-Type") },
        plan_png: { kind: await figureKind(png.data), type: png.response.headers.get("Content-Type") },
        job_status: job.status,
        job_location: submitted.response.headers.get("Location"),
        job_id: job.id,
        job_links_self: job.links.self,
        phases: job.progress.phases.map((p) => [p.name, p.role, p.completed]),
        best_params: tuned.best_params,
        best_objective_b: tuned.best_objective_b,
        history_length: tuned.history.length,
        dls_lambda: tuned.dls_baseline?.lambda ?? null,
        event_kinds: [...events.data.matchAll(/^event: (\w+)$/gm)].map((m) => m[1]),
        job_figure: { kind: await figureKind(convergence.data), type: convergence.response.headers.get("Content-Type") },
        deleted: [deletedPlan.response.status, deletedJob.response.status, deletedRobot.response.status],
        missing_status: missing.response.status,
        missing_problem_status: problem?.status ?? null,
    };
    process.stdout.write(JSON.stringify(summary) + "\n");
}

const [baseUrl] = process.argv.slice(2);
if (baseUrl === undefined) {
    process.stderr.write("usage: node build/flow.js <base URL>\n");
    process.exit(2);
}
await main(baseUrl);
