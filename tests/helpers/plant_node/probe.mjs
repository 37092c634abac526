// A second OPC UA stack against `monoguide plant`: node-opcua's client, not asyncua. Each probe prints one JSON
// line, in the shape of tests/helpers/plant_wire.py's Answer: {"refused": status name or null, "step", "value"}.
// Usage: node probe.mjs PROBE URL CERT.pem KEY.pem USER PASSWORD
import { OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, makeBrowsePath } from "node-opcua-client";

const [probe, url, certificateFile, privateKeyFile, userName, password] = process.argv.slice(2);
const MV = "http://opcfoundation.org/UA/MachineVision";

function answer(refused, step, value = null) {
    console.log(JSON.stringify({ refused, step, value }));
}

function client(mode, policy) {
    return OPCUAClient.create({
        applicationName: "node-opcua probe", applicationUri: "urn:test:node-probe",
        securityMode: mode, securityPolicy: policy, certificateFile, privateKeyFile,
        endpointMustExist: false, connectionStrategy: { maxRetry: 0, initialDelay: 100 },
        requestedSessionTimeout: 60000, clientCertificateManager: undefined,
    });
}

function statusName(error) {
    const text = String(error && error.message || error);
    const found = text.match(/Bad[A-Za-z]+/);
    return found ? found[0] : "Error";
}

async function results(session) {
    // by the published browse names only: Objects/VisionSystem is found by its children's names
    const ns = (await session.readNamespaceArray()).indexOf(MV);
    const own = (await session.readNamespaceArray()).indexOf("urn:monoguide");
    const paths = [
        makeBrowsePath("ObjectsFolder", `/${own}:VisionSystem/${ns}:VisionStateMachine.CurrentState.Number`),
        makeBrowsePath("ObjectsFolder", `/${own}:VisionSystem/${ns}:ResultManagement/${ns}:Results.${own}:Result01`),
        makeBrowsePath("ObjectsFolder", `/${own}:VisionSystem/${ns}:ResultManagement/${ns}:GetResultById`),
        makeBrowsePath("ObjectsFolder", `/${own}:VisionSystem/${ns}:ResultManagement`),
    ];
    const found = await session.translateBrowsePath(paths);
    const [number, result01, method, management] = found.map((f) => f.targets && f.targets[0] && f.targets[0].targetId);
    const state = await session.read({ nodeId: number, attributeId: AttributeIds.Value });
    const [job, resultId] = (await session.translateBrowsePath([makeBrowsePath(result01, `.${ns}:JobId`),
        makeBrowsePath(result01, `.${ns}:ResultId`)])).map((f) => f.targets[0].targetId);
    const [jobValue, resultIdValue] = await session.read([{ nodeId: job, attributeId: AttributeIds.Value },
        { nodeId: resultId, attributeId: AttributeIds.Value }]);
    const jobId = jobValue.value.value && jobValue.value.value.id;
    const called = await session.call({  // the ResultId as read, handed back: GetResultById(ResultId, Timeout)
        objectId: management, methodId: method,
        inputArguments: [{ dataType: "ExtensionObject", value: resultIdValue.value.value },
            { dataType: "Int32", value: 0 }],
    });
    const result = called.outputArguments[1].value;
    return { stateNumber: state.value.value, jobId, callStatus: called.statusCode.name,
             resultId: result && result.resultId && result.resultId.id, jobOfResult: result && result.jobId && result.jobId.id,
             error: called.outputArguments[2].value };
}

async function main() {
    if (probe === "results" || probe === "wrong-password") {  // results with an untrusted certificate: refused
        const c = client(MessageSecurityMode.SignAndEncrypt, SecurityPolicy.Basic256Sha256);
        await c.connect(url);
        try {
            const session = await c.createSession({ type: 1, userName,
                password: probe === "wrong-password" ? "wrong" : password });
            try {
                answer(null, "read", await results(session));
            } finally {
                await session.close();
            }
        } catch (error) {
            answer(statusName(error), "activation", String(error && error.message).slice(0, 300));
        } finally {
            await c.disconnect();
        }
    } else {
        answer("UnknownProbe", probe);
    }
}

main().then(() => process.exit(0), (error) => { answer(statusName(error), "probe"); process.exit(0); });
