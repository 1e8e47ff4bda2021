"""The HTTP status page at ``/``: one static HTML file that polls /status and follows /events."""

STATUS_PAGE = """<!doctype html>
<html><head><meta charset="utf-8"><title>gcs-pdm</title>
<style>
body{font-family:system-ui,sans-serif;margin:1.5em;background:#fafafa;color:#222}
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th{background:#eee}.bad{color:#b00;font-weight:bold}.ok{color:#070}
#log{font-family:monospace;font-size:90%;white-space:pre-wrap;background:#fff;border:1px solid #ccc;padding:.5em;
max-height:20em;overflow:auto}
</style></head><body>
<h1>gcs-pdm</h1>
<p id="head">connecting…</p>
<p id="vehicle"></p><table id="readiness"></table>
<h2>Packs</h2><table id="packs"></table>
<h2>Motors</h2><table id="motors"></table>
<h2>Mission</h2><p id="mission"></p>
<h2>Events</h2><div id="log"></div>
<p><a href="/docs">API (OpenAPI)</a> · <a href="/missions/history">plans</a> · <a href="/faults">faults</a></p>
<script>
const f=(v,d=2)=>v==null?"–":(typeof v==="number"?v.toFixed(d):v);
async function tick(){
  try{
    const s=await (await fetch('/status')).json();
    document.getElementById('head').innerHTML=
      `link <b class="${s.link.connected?'ok':'bad'}">${s.link.connected?'up':'down'}</b> · t=${f(s.time_s,1)} s · `+
      `mode ${f(s.mode)} · policy ${f(s.policy)} · params ${f(s.parameter_set)} · `+
      `pos ${f(s.position.lat_deg,6)}, ${f(s.position.lon_deg,6)}, ${f(s.position.relative_alt_m,0)} m`+
      (s.failed?` · <b class="bad">FAILED: ${s.failed}</b>`:'');
    const v=s.vehicle||{};
    document.getElementById('vehicle').innerHTML=`vehicle <b>${f(v.name)}</b> (${f(v.source)})`+
      (v.provisional?` · <b class="bad">provisional</b>: ${(v.notes||[]).join('; ')} · ${v.save||''}`:'')+
      (v.waiting_for?` · ${v.waiting_for}`:'');
    let r='';
    for(const[k,why] of Object.entries(s.readiness||{})) r+=`<tr><th>${k}</th><td class="${why==='ready'?'ok':'bad'}" style="text-align:left">${why}</td></tr>`;
    document.getElementById('readiness').innerHTML=r;
    let h='<tr><th>pack</th><th>V</th><th>A</th><th>°C</th><th>SoC</th><th>± </th><th>cut-off in (s)</th><th>±</th></tr>';
    for(const[n,p] of Object.entries(s.packs)) h+=`<tr><th>${n}</th><td>${f(p.voltage_v)}</td><td>${f(p.current_a,1)}</td>`+
      `<td>${f(p.temperature_c,1)}</td><td>${f(p.soc,3)}</td><td>${f(p.soc_sd,3)}</td><td>${f(p.time_to_cutoff_s,0)}</td><td>${f(p.time_to_cutoff_sd,0)}</td></tr>`;
    document.getElementById('packs').innerHTML=h;
    h='<tr><th>motor</th><th>A</th><th>rpm</th><th>°C</th><th>health</th><th>fault</th></tr>';
    for(const[n,m] of Object.entries(s.motors)) h+=`<tr><th>${n}</th><td>${f(m.current_a,1)}</td><td>${f(m.rpm,0)}</td>`+
      `<td>${f(m.temperature_c,1)}</td><td class="${m.health<0.99?'bad':'ok'}">${f(m.health,2)}</td><td>${m.fault?m.fault.kind+' '+f(m.fault.magnitude,2):'–'}</td></tr>`;
    document.getElementById('motors').innerHTML=h;
    document.getElementById('mission').textContent=
      `current item ${f(s.mission.current_seq)} of ${f(s.mission.count)}, last reached ${f(s.mission.last_reached_seq)}`;
  }catch(e){document.getElementById('head').textContent='no service: '+e}
}
setInterval(tick,1000);tick();
const log=document.getElementById('log');
const es=new EventSource('/events?since=0');
for(const k of ['fault','plan','upload','mission','job','policy','statustext','link','failure','vehicle'])
  es.addEventListener(k,e=>{const d=JSON.parse(e.data);
    log.textContent=`[${d.seq}] ${k}: ${JSON.stringify(d.data)}\\n`+log.textContent;});
</script></body></html>
"""
