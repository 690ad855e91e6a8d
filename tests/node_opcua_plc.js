// A PLC's OPC UA server played by node-opcua (an implementation independent of asyncua), for tests/test_plc_push.py.
//
// node node_opcua_plc.js SPEC.json: SPEC holds {"port", "user", "password", "nodes": [{"id", "type", "length",
// "value", "writable"}]}: each node a variable of the type a PLC's REAL, LREAL, STRING or INT publishes ("Float",
// "Double", "String", "Int16"), an array of "length" elements where that is given (ValueRank 1, or the node's "rank"
// where it gives one: a PLC may state 0, "one or more dimensions", for an array), under the namespace
// "urn:piezopreload:test-plc" with the string node id "id". Sessions need the user and password (anonymous ones are
// refused). The script prints "listening <endpoint>" once it serves, and ends on SIGTERM or when its input closes.
"use strict";
const fs = require("fs");
const { OPCUAServer } = require("node-opcua-server");
const { Variant, DataType, VariantArrayType } = require("node-opcua-variant");
const { StatusCodes } = require("node-opcua-status-code");

const spec = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));

function variant(type, length, value) {
    const dataType = DataType[type];
    if (length === undefined || length === null) {
        return new Variant({ dataType, value });
    }
    const arrays = { Float: Float32Array, Double: Float64Array, Int16: Int16Array };
    const data = arrays[type] ? new arrays[type](value) : value;
    return new Variant({ dataType, arrayType: VariantArrayType.Array, value: data });
}

async function main() {
    const server = new OPCUAServer({
        port: spec.port,
        resourcePath: "/plc",
        allowAnonymous: false,
        userManager: { isValidUser: (user, password) => user === spec.user && password === spec.password },
        buildInfo: { productName: "test PLC (node-opcua)" },
    });
    await server.initialize();
    const ns = server.engine.addressSpace.registerNamespace("urn:piezopreload:test-plc");
    const folder = ns.addFolder(server.engine.addressSpace.rootFolder.objects, { browseName: "PLC" });
    for (const node of spec.nodes) {
        const array = node.length !== undefined && node.length !== null;
        const rank = node.rank ?? (array ? 1 : -1);
        let current = variant(node.type, node.length, node.value);
        ns.addVariable({
            componentOf: folder,
            nodeId: `s=${node.id}`,
            browseName: node.id,
            dataType: node.type,
            valueRank: rank,
            arrayDimensions: array && rank > 0 ? [node.length] : null,  // node-opcua: none for a ValueRank <= 0
            accessLevel: node.writable ? "CurrentRead | CurrentWrite" : "CurrentRead",
            userAccessLevel: node.writable ? "CurrentRead | CurrentWrite" : "CurrentRead",
            value: {
                get: () => current,
                set: (v) => {
                    if (!node.writable) return StatusCodes.BadNotWritable;
                    current = variant(node.type, node.length, Array.isArray(v.value) || ArrayBuffer.isView(v.value)
                        ? Array.from(v.value) : v.value);
                    return StatusCodes.Good;
                },
            },
        });
    }
    await server.start();
    console.log(`listening ${server.getEndpointUrl()}`);
    const stop = async () => { await server.shutdown(0); process.exit(0); };
    process.on("SIGTERM", stop);
    process.stdin.on("end", stop);
    process.stdin.resume();
}

main().catch((err) => { console.error(err); process.exit(1); });
